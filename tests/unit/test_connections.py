"""The line thread's poll over the clients (mbgw.slave.connections), over real sockets."""
import os
import socket

import pytest

from mbgw.slave.connections import Connections
from mbgw.ops.counters import Counters
from mbgw.slave.client import Client
from tests.modbus import mbap, read_holding


class Rig:
    def __init__(self) -> None:
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self.requests: list = []
        self.closed: list = []
        self.counters = Counters()
        self.fail = False
        self.connections = Connections(self.wake_fd, self.on_request, self.closed.append,
                                       self.counters)
        self.peers: list[socket.socket] = []

    def on_request(self, client, tid, unit, pdu) -> None:
        if self.fail:
            raise RuntimeError("a bug")
        self.requests.append((client.id, tid, unit, pdu))

    def connect(self) -> tuple[Client, socket.socket]:
        ours, theirs = socket.socketpair()
        ours.setblocking(False)
        theirs.settimeout(5)
        client = Client(ours, "local", "peer", "local")
        self.connections.adopt(client)
        self.peers.append(theirs)
        return client, theirs

    def close(self) -> None:
        self.connections.close_all()
        for peer in self.peers:
            peer.close()
        os.close(self.wake_fd)


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_an_adopted_client_is_read_and_its_frames_handed_on(rig):
    client, peer = rig.connect()
    assert not rig.connections.wait(5000)            # the adoption's wake-up
    peer.sendall(mbap(7, 1, read_holding(0, 2)) + mbap(8, 1, read_holding(2, 2)))
    assert not rig.connections.wait(5000)
    assert rig.requests == [(client.id, 7, 1, read_holding(0, 2)),
                            (client.id, 8, 1, read_holding(2, 2))]


def test_a_frame_split_over_two_reads_is_handed_on_once_whole(rig):
    client, peer = rig.connect()
    rig.connections.wait(5000)
    frame = mbap(7, 1, read_holding(0, 2))
    peer.sendall(frame[:5])
    rig.connections.wait(5000)
    assert rig.requests == []
    peer.sendall(frame[5:])
    rig.connections.wait(5000)
    assert rig.requests == [(client.id, 7, 1, read_holding(0, 2))]


def test_a_bad_header_closes_that_connection_only(rig):
    bad, bad_peer = rig.connect()
    good, good_peer = rig.connect()
    rig.connections.wait(5000)
    bad_peer.sendall(b"\x00\x01\x00\x05\x00\x06\x01\x03\x00\x00\x00\x01")   # protocol id 5
    rig.connections.wait(5000)
    assert rig.closed == [bad] and bad.closed
    assert rig.counters.connections_bad_header == 1
    assert bad_peer.recv(100) == b""
    good_peer.sendall(mbap(1, 1, read_holding(0, 1)))
    rig.connections.wait(5000)
    assert rig.requests == [(good.id, 1, 1, read_holding(0, 1))]


def test_a_connection_the_client_ends_is_closed(rig):
    client, peer = rig.connect()
    rig.connections.wait(5000)
    peer.close()
    rig.connections.wait(5000)
    assert rig.closed == [client] and client.closed


def test_a_shutdown_from_another_thread_ends_up_closed_by_the_line_thread(rig):
    client, peer = rig.connect()
    rig.connections.wait(5000)
    client.shutdown()
    rig.connections.wait(5000)
    assert rig.closed == [client]
    assert peer.recv(100) == b""


def test_a_bug_handling_a_request_costs_that_connection_only(rig):
    client, peer = rig.connect()
    rig.connections.wait(5000)
    rig.fail = True
    peer.sendall(mbap(1, 1, read_holding(0, 1)))
    rig.connections.wait(5000)                       # logs the error, does not raise
    assert rig.closed == [client]


def test_serial_input_is_reported(rig):
    r, w = os.pipe()
    try:
        os.write(w, b"\x01")
        assert rig.connections.wait(5000, r)
    finally:
        os.close(r)
        os.close(w)


def test_waiting_without_a_timeout_returns_when_woken(rig):
    os.eventfd_write(rig.wake_fd, 1)
    assert not rig.connections.wait(-1)
