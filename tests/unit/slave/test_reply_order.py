"""A connection's replies reach the client whole and in order, also when its socket is full
and replies have to wait in the gateway; a client that does not read its replies is not
read either, once a backlog has built up."""
import socket

import pytest

from mbgw.line import native
from mbgw.slave.connections import OUTPUT_LIMIT, Client


def frames_from(data: bytes) -> list[int]:
    tids = []
    while data:
        length = int.from_bytes(data[4:6], "big")
        tids.append(int.from_bytes(data[:2], "big"))
        data = data[6 + length:]
    return tids


@pytest.fixture
def pair():
    """(Client on one end, the peer's socket), both buffers small so they fill quickly."""
    ours, theirs = socket.socketpair()
    ours.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    theirs.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    ours.setblocking(False)
    client = Client(ours, "local", "peer", "local")
    yield client, theirs
    client.close()
    theirs.close()


def reply(tid: int) -> bytes:
    return native.frame(tid, 1, b"\x03\xfa" + bytes(250))


def test_replies_keep_their_order_when_the_socket_fills_up(pair):
    client, peer = pair
    for tid in range(400):
        client.send(reply(tid))
    assert client.output_waiting, "the socket never filled: the backlog was not exercised"
    peer.settimeout(5)
    received = b""
    expected = sum(len(reply(tid)) for tid in range(400))
    while len(received) < expected:
        received += peer.recv(65536)
        client.flush()
    assert frames_from(received) == list(range(400))
    assert not client.output_waiting


def test_a_client_that_does_not_read_its_replies_is_not_read_either(pair):
    client, _ = pair
    assert client.readable
    tid = 0
    while client.readable:
        client.send(reply(tid))
        tid += 1
    assert OUTPUT_LIMIT <= sum(len(reply(t)) for t in range(tid))
    assert client.output_waiting
