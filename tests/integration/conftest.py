import os
import resource
import socket

import pytest

from tests.harness import Gateway, Peer, free_port
from tests.integration.test_master import BAUD
from tests.modbus import Client


@pytest.fixture
def state_directory(tmp_path, monkeypatch):
    """The daemons' state directory ($STATE_DIRECTORY, as systemd sets it): the test's own,
    where table-persist files may be (and the table's file goes by default)."""
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    return tmp_path


@pytest.fixture
def many_fds():
    """The test process may hold thousands of sockets (RLIMIT_NOFILE raised meanwhile)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 8192), hard))
    yield
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


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


# --- master mode: pymodbus Modbus TCP servers on loopback addresses, `mbgw master` on a pty

@pytest.fixture
def servers_at():
    """servers_at(*hosts, silent=(), port=None) -> (port, Peer): pymodbus servers on these
    loopback addresses and on the silent ones (which never answer), all on one port;
    stopped after the test."""
    started = []

    def start(*hosts: str, silent=(), port: int | None = None):
        port = port or free_port()
        args = [str(port), *hosts, *silent]
        if silent:
            args += ["--silent", *silent]
        peer = Peer("pymodbus_tcp_servers.py", *args)
        started.append(peer)
        return port, peer

    yield start
    for peer in started:
        peer.stop()


@pytest.fixture
def start_master(pty_pair, start_gateway):
    """start_master(*options) -> a ready `mbgw master` on the pty at BAUD; stopped after."""
    def start(*options: str) -> Gateway:
        return start_gateway(pty_pair.gateway, "--baudrate", BAUD, *options, mode="master",
                             listen=False)
    return start


@pytest.fixture
def line(pty_pair):
    """The master's end of the line as a raw fd."""
    fd = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)
    yield fd
    os.close(fd)
