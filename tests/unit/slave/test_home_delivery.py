"""A target's outcome delivered by the target's own thread while the face's thread is idle
(Router._completed under Connections.home), else handed over through the face's eventfd."""
import os
import socket
import threading

import pytest

from mbgw.config.model import SerialConfig, SlaveConfig
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.routing.queue import Exchange, Scheduler
from mbgw.slave.connections import Client
from mbgw.slave.server import TcpServer
from tests.modbus import mbap
from tests.wait import until

REPLY = bytes((3, 2, 0x12, 0x34))


class Face:
    """A TcpServer with one client on a socketpair; this test's thread is its owner."""

    def __init__(self) -> None:
        self.scheduler = Scheduler()
        self.server = TcpServer(SlaveConfig(SerialConfig("/dev/null")), self.scheduler,
                                Counters(), lambda: True, DeviceHealth())
        self.connections = self.server.connections
        ours, self.peer = socket.socketpair()
        ours.setblocking(False)
        self.peer.settimeout(5)
        self.client = Client(ours, "local", "peer", "local")
        self.connections.adopt(self.client)
        self.connections.wait(0)         # adopted, polled
        self.idle: threading.Thread | None = None

    def go_idle(self) -> None:
        """The owner's idle poll(), on a thread of its own until woken."""
        self.idle = threading.Thread(target=self.connections.wait, args=(-1,))
        self.idle.start()
        until(lambda: not self.connections.home.locked(), "the face idle", 5)

    def outcome(self, tid: int) -> None:
        """A target's thread answers the client's exchange (its done: Router._completed)."""
        router = self.server.router
        self.client.admitted()
        exchange = Exchange(self.client, 1, bytes((3, 0, 0, 0, 1)), 0, router._completed,
                            (self.client, tid, 1, "meters"))
        target = threading.Thread(target=exchange.done, args=(exchange, REPLY, "reply"))
        target.start()
        target.join()

    def woken(self) -> bool:
        try:
            return os.eventfd_read(self.scheduler.wake_fd) > 0
        except BlockingIOError:
            return False

    def close(self) -> None:
        if self.idle is not None:
            self.scheduler.wake()
            self.idle.join(5)
        self.connections.close_all()
        self.peer.close()
        self.scheduler.close()


@pytest.fixture
def face():
    f = Face()
    yield f
    f.close()


def test_an_idle_face_is_answered_by_the_targets_thread_without_a_wake_up(face):
    face.go_idle()
    face.outcome(7)
    assert face.peer.recv(64) == mbap(7, 1, REPLY)
    assert face.client.in_flight == 0
    assert face.idle is not None and face.idle.is_alive()     # never woken
    face.scheduler.wake()
    face.idle.join(5)
    assert not face.idle.is_alive()
    assert face.connections.home.locked()       # its owner's again


def test_a_busy_face_is_handed_the_outcome_and_delivers_it_in_order(face):
    face.outcome(1)                 # the owner holds the home: busy
    face.outcome(2)
    face.peer.settimeout(0.05)
    with pytest.raises(TimeoutError):
        face.peer.recv(64)
    face.connections.wait(0)        # woken: delivers both, in the order they came
    face.peer.settimeout(5)
    data = b""
    while len(data) < 2 * len(mbap(1, 1, REPLY)):
        data += face.peer.recv(64)
    assert data == mbap(1, 1, REPLY) + mbap(2, 1, REPLY)


def test_a_client_that_changed_meanwhile_wakes_the_face(face):
    """A reply the client's socket would not take waits in its output: the face's thread
    must poll that client for output now, so it is woken."""
    face.client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    big = bytes((3, 250)) + bytes(250)
    face.go_idle()
    router = face.server.router
    while not face.client.output_waiting:       # the peer reads nothing: its buffers fill
        face.client.admitted()
        exchange = Exchange(face.client, 1, bytes((3, 0, 0, 0, 125)), 0, router._completed,
                            (face.client, 1, 1, "meters"))
        exchange.done(exchange, big, "reply")
    assert face.idle is not None
    face.idle.join(5)
    assert not face.idle.is_alive()             # woken, it polls the client anew
