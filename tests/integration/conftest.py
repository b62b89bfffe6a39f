import socket

import pytest

from tests.modbus import Client


@pytest.fixture
def recording_peer(pty_pair, start_peer, tmp_path):
    """recording_peer(script, *options) -> the path of the record a scripted slave from
    tests/peers (fault_slave.py, paced_slave.py) keeps of what it receives; the peer is ready
    on pty_pair's device end."""
    def start(script: str, *options: str):
        record = tmp_path / "record.txt"
        start_peer(script, pty_pair.device, "--record", str(record), *options)
        return record
    return start


@pytest.fixture
def client():
    """client(gw, timeout=REPLY_S) -> a raw tests.modbus.Client to the gateway; closed after
    the test."""
    clients = []

    def connect(gw, **options) -> Client:
        c = Client(gw.port, **options)
        clients.append(c)
        return c

    yield connect
    for c in clients:
        c.close()


@pytest.fixture
def socket_ends():
    """(the gateway's end of a client connection, non-blocking; the client's end), for the
    tests of the C paths that read and write client sockets."""
    ours, theirs = socket.socketpair()
    ours.setblocking(False)
    theirs.settimeout(1.0)
    yield ours, theirs
    ours.close()
    theirs.close()
