"""The table reader (mbgw.slave.table_reader) over real sockets: its name in the OS, and
the clients it polls following their readability as Connections does."""
import os
import socket
import threading
from pathlib import Path

import pytest

from mbgw.slave.connections import MAX_IN_FLIGHT, Client
from mbgw.slave.table_reader import THREAD_NAME, Gate, TableReader
from tests.modbus import mbap, read_holding
from tests.unit.slave.test_connections import Rig, readable
from tests.wait import until

WAIT_S = 5.0


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


class Reader:
    """A TableReader over rig's connections, started with the gate held by the test (as the
    line thread holds it): what it reads is recorded; the test lets it serve with serve()."""

    def __init__(self, rig: Rig) -> None:
        self.gate = Gate()
        self.gate.take_for_line()
        self.read: list = []
        self.served = threading.Event()
        self.thread = TableReader(self.gate, rig.connections, rig.wake_fd, self._on_request,
                                  None)
        self.thread.start()

    def _on_request(self, client, tid, unit, pdu, responder) -> None:
        self.read.append((client.id, tid, unit, pdu))
        self.served.set()

    def serve(self) -> None:
        """Let go of the gate until the reader has read a request, then take it back."""
        self.served.clear()
        self.gate.release()
        try:
            assert self.served.wait(WAIT_S), "the reader read no request"
        finally:
            self.gate.take_for_line()

    def stop(self) -> None:
        self.thread.stop()
        self.gate.release()
        self.thread.join(WAIT_S)
        assert not self.thread.is_alive()


def test_the_reader_has_its_name_in_ps_and_top(rig):
    reader = Reader(rig)
    try:
        comm = Path(f"/proc/self/task/{reader.thread.native_id}/comm")
        assert until(lambda: comm.read_text().strip() == THREAD_NAME,
                     lambda: f"the reader named {THREAD_NAME}, not {comm.read_text()!r}",
                     WAIT_S)
        assert THREAD_NAME.startswith("mbgw-") and len(THREAD_NAME) <= 15
    finally:
        reader.stop()


class CountingClient(Client):
    """A client that counts how often its readability is looked at."""
    looked = 0

    @property
    def readable(self) -> bool:
        self.looked += 1
        return super().readable


def counting_client(rig: Rig) -> tuple[CountingClient, socket.socket]:
    ours, theirs = socket.socketpair()
    ours.setblocking(False)
    theirs.settimeout(WAIT_S)
    rig.peers.append(theirs)
    client = CountingClient(ours, "local", "peer", "local")
    rig.connections.adopt(client)
    return client, theirs


def test_a_wake_looks_only_at_the_clients_that_changed(rig):
    clients = [counting_client(rig)[0] for _ in range(3)]
    rig.connections.wait(WAIT_S * 1000)             # the adoptions' wake-up
    rig.connections.wait(0)
    looked = [c.looked for c in clients]
    for _ in range(5):
        os.eventfd_write(rig.wake_fd, 1)
        rig.connections.wait(WAIT_S * 1000)
    assert [c.looked for c in clients] == looked    # no scan of them all per wake
    for _ in range(MAX_IN_FLIGHT):
        clients[1].admitted()
    rig.connections.wait(0)
    assert [c.looked - n for c, n in zip(clients, looked, strict=True)] == [0, 1, 0]


def test_the_reader_reads_a_client_only_while_it_may_be_read(rig):
    """A client with 16 requests in the gateway is not read by the reader (as the line
    thread does not read it) until one is answered; one closed is no longer polled."""
    reader = Reader(rig)
    try:
        full, full_peer = rig.connect()
        other, other_peer = rig.connect()
        rig.connections.wait(WAIT_S * 1000)         # the adoptions, by the "line thread"
        for _ in range(MAX_IN_FLIGHT):
            full.admitted()
        rig.connections.update()
        full_peer.sendall(mbap(1, 1, read_holding(0, 1)))
        other_peer.sendall(mbap(2, 1, read_holding(0, 1)))
        readable(full, other)
        reader.serve()
        assert reader.read == [(other.id, 2, 1, read_holding(0, 1))]

        full.answered()                             # room again
        rig.connections.update()
        os.eventfd_write(rig.wake_fd, 1)            # the reader polls again
        reader.serve()
        assert reader.read[1:] == [(full.id, 1, 1, read_holding(0, 1))]

        other_peer.close()
        reader.served.clear()
        reader.gate.release()
        assert until(lambda: other.closed, "the reader closing the ended client", WAIT_S)
        reader.gate.take_for_line()
        full_peer.sendall(mbap(3, 1, read_holding(0, 1)))
        reader.serve()
        assert reader.read[2:] == [(full.id, 3, 1, read_holding(0, 1))]
    finally:
        reader.stop()
