"""The line thread's poll over the clients (mbgw.slave.connections), over real sockets."""
import os
import select
import socket
import time

import pytest

from mbgw.line import native
from mbgw.ops.counters import Counters
from mbgw.routing.queue import Job, Scheduler
from mbgw.slave.connections import MAX_IN_FLIGHT, Client, Connections
from tests.modbus import mbap, read_holding


class Rig:
    def __init__(self) -> None:
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self.requests: list = []
        self.arrivals: dict[int, list[int]] = {}     # client id: arrived_ns of its requests
        self.closed: list = []
        self.counters = Counters()
        self.fail = False
        self.connections = Connections(self.wake_fd, self.on_request, self.closed.append,
                                       self.counters)
        self.peers: list[socket.socket] = []
        self.listener: socket.socket | None = None

    def on_request(self, client, tid, unit, pdu) -> None:
        if self.fail:
            raise RuntimeError("a bug")
        self.requests.append((client.id, tid, unit, pdu))
        self.arrivals.setdefault(client.id, []).append(client.arrived_ns)

    def connect(self) -> tuple[Client, socket.socket]:
        ours, theirs = socket.socketpair()
        return self._adopt(ours, theirs)

    def connect_tcp(self) -> tuple[Client, socket.socket]:
        """Over loopback TCP from a listener that dates arrivals, as the gateway's does."""
        if self.listener is None:
            self.listener = socket.create_server(("127.0.0.1", 0))
            native.stamp_arrivals(self.listener.fileno())
            self._until_arrivals_are_dated()
        theirs = socket.create_connection(self.listener.getsockname())
        ours, _ = self.listener.accept()
        return self._adopt(ours, theirs)

    def _until_arrivals_are_dated(self) -> None:
        """The kernel turns its receive timestamps on in deferred work when the first
        socket asks for them; what arrives before is undated (read as arrived now)."""
        assert self.listener is not None
        reader = native.ClientReader(16)
        deadline = time.monotonic() + 5
        with socket.create_connection(self.listener.getsockname()) as theirs:
            ours, _ = self.listener.accept()
            with ours:
                while True:
                    theirs.sendall(b"x")
                    sent = time.monotonic_ns()
                    readable_fd(ours.fileno())
                    reader.read(ours.fileno())
                    if reader.arrived_ns <= sent:
                        return
                    assert time.monotonic() < deadline, "the kernel dates no arrival"
                    os.sched_yield()

    def _adopt(self, ours: socket.socket, theirs: socket.socket) -> tuple[Client, socket.socket]:
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
        if self.listener is not None:
            self.listener.close()
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


# --- the line's order: when requests arrived, not when they were read ---

def test_a_request_is_dated_when_it_arrived_not_when_it_was_read(rig):
    client, peer = rig.connect_tcp()
    rig.connections.wait(5000)
    before = time.monotonic_ns()
    peer.sendall(mbap(1, 1, read_holding(0, 1)))
    sent = time.monotonic_ns()
    read = time.monotonic_ns()
    rig.connections.wait(5000)
    (arrived,) = rig.arrivals[client.id]
    assert before <= arrived <= sent < read


def test_requests_read_in_one_poll_keep_the_order_they_arrived_in(rig):
    """The root of issue 13's overtaking: after a transaction, every client that sent
    meanwhile is read in one poll, in fd order; their turns must follow the arrivals."""
    scheduler = Scheduler()
    submit = rig.on_request

    def on_request(client, tid, unit, pdu):
        submit(client, tid, unit, pdu)
        scheduler.submit(client.queue, Job(client, tid, unit, pdu, client.arrived_ns))
    rig.connections._on_request = on_request
    first_fd, first_peer = rig.connect_tcp()
    later_fd, later_peer = rig.connect_tcp()
    rig.connections.wait(5000)
    assert first_fd.fd < later_fd.fd
    later_peer.sendall(mbap(1, 1, read_holding(0, 1)))      # the higher fd sends first
    first_peer.sendall(mbap(2, 1, read_holding(0, 1)))
    while len(rig.requests) < 2:
        rig.connections.wait(5000)
    try:
        assert [scheduler.take().tid for _ in range(2)] == [1, 2]
    finally:
        scheduler.close()


def test_the_idle_lines_shortcut_takes_a_client_only_when_it_alone_is_ready(rig):
    """With two clients ready, which came first is known only by reading both."""
    taken = []

    def take(client):
        taken.append(client)
        return client.receive(rig.connections._reader)
    a, a_peer = rig.connect_tcp()
    b, b_peer = rig.connect_tcp()
    rig.connections.wait(5000)
    a_peer.sendall(mbap(1, 1, read_holding(0, 1)))
    b_peer.sendall(mbap(2, 1, read_holding(0, 1)))
    readable(a, b)
    rig.connections.wait(5000, take=take)
    assert taken == [] and len(rig.requests) == 2
    a_peer.sendall(mbap(3, 1, read_holding(0, 1)))
    readable(a)
    rig.connections.wait(5000, take=take)
    assert taken == [a] and len(rig.requests) == 3


def test_what_a_held_back_client_sent_is_dated_from_when_it_is_read_again(rig):
    """A client with 16 requests in the gateway (or replies it does not read) is not read;
    what it sent meanwhile does not go ahead of the clients that waited."""
    client, peer = rig.connect_tcp()
    rig.connections.wait(5000)
    for _ in range(MAX_IN_FLIGHT):
        client.admitted()
    rig.connections.wait(0)
    peer.sendall(mbap(1, 1, read_holding(0, 1)))
    sent = time.monotonic_ns()
    readable(client)
    rig.connections.wait(0)
    assert rig.requests == []
    client.answered()
    resumed = time.monotonic_ns()
    rig.connections.wait(5000)
    (arrived,) = rig.arrivals[client.id]
    assert sent < resumed <= arrived


def readable(*clients: Client) -> None:
    """Until input waits on each client's socket."""
    for client in clients:
        readable_fd(client.fd)


def readable_fd(fd: int) -> None:
    probe = select.poll()
    probe.register(fd, select.POLLIN)
    assert probe.poll(5000)
