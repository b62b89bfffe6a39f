"""Strict fairness on the line (docs/architecture.md, slave path step 4): waiting clients are
served round-robin in the arrival order of their turns, so no request is overtaken by a
request of another client that arrived after it, and a request waits at most one
transaction of each other waiting client -- one stout for a silent device.

Closed-loop clients (one request at a time, the next as soon as the reply is in) read unit 1
of the scripted slave (peers/fault_slave.py) while another reads its silent unit 2; the
line's order is the order of the frames the slave records, each request naming its client
and its number in the register it reads.  A request's arrival is bracketed by the client's
clock (CLOCK_MONOTONIC, the slave's clock too) read before and after its send, so only
arrivals that are surely later count as later."""
import selectors
import socket
import struct
import time
from dataclasses import dataclass, field

import pytest

from tests.integration.slave.test_faults import received
from tests.modbus import mbap, read_holding

pytestmark = [pytest.mark.integration, pytest.mark.serial]

STOUT_MS = 150
HEALTHY, SILENT = 1, 2          # fault_slave.py: unit 1 answers, unit 2 never does
RUN_S = 3.0


@dataclass
class Sent:
    client: int
    number: int
    before: float               # the client's clock just before its send ...
    after: float                # ... and just after: the request arrived in between


@dataclass
class LoopClient:
    """A Modbus TCP client whose requests carry (its index, their number) as the register
    address: index << 8 | number % 256.  pipeline: requests sent at once, the next batch
    when all are answered."""
    index: int
    unit: int
    port: int
    pipeline: int = 1
    sock: socket.socket = field(init=False)
    number: int = 0
    waiting: int = 0
    buf: bytes = b""

    def __post_init__(self) -> None:
        self.sock = socket.create_connection(("127.0.0.1", self.port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def send(self, log: list[Sent]) -> None:
        frames = []
        for _ in range(self.pipeline):
            address = self.index << 8 | self.number % 256
            frames.append(mbap(self.number % 65536, self.unit, read_holding(address, 1)))
            self.number += 1
        before = time.monotonic()
        self.sock.sendall(b"".join(frames))
        after = time.monotonic()
        for n in range(self.number - self.pipeline, self.number):
            log.append(Sent(self.index, n, before, after))
        self.waiting = self.pipeline

    def replies(self) -> int:
        """Read what came; the number of whole replies it completed."""
        data = self.sock.recv(4096)
        if not data:
            raise ConnectionError(f"client {self.index}: the gateway closed the connection")
        self.buf += data
        done = 0
        while len(self.buf) >= 6:
            (length,) = struct.unpack(">H", self.buf[4:6])
            if len(self.buf) < 6 + length:
                break
            self.buf = self.buf[6 + length:]
            done += 1
        self.waiting -= done
        return done


def run_loop(clients: list[LoopClient], seconds: float) -> list[Sent]:
    """Every client in a closed loop for seconds; what each sent, and when."""
    log: list[Sent] = []
    sel = selectors.DefaultSelector()
    for c in clients:
        sel.register(c.sock, selectors.EVENT_READ, c)
        c.send(log)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for key, _ in sel.select(0.5):
            c = key.data
            if c.replies() and not c.waiting:
                c.send(log)
    sel.close()
    for c in clients:
        c.sock.close()
    return log


def line_order(record) -> list[tuple[int, int, float]]:
    """(client, number mod 256, arrival at the slave) of each request, in the line's order."""
    order = []
    for when, frame in received(record):
        assert frame[1] == 0x03, frame.hex(" ")
        order.append((frame[2], frame[3], when))
    return order


def on_the_line(log: list[Sent], order) -> list[tuple[Sent, float]]:
    """Each request that reached the line, with its arrival at the slave, in line order.  A
    client's requests reach the line in its own order (checked), numbered mod 256."""
    pending: dict[int, list[Sent]] = {}
    for sent in log:
        pending.setdefault(sent.client, []).append(sent)
    taken = {client: 0 for client in pending}
    matched = []
    for client, low, when in order:
        sent = pending[client][taken[client]]
        assert sent.number % 256 == low, f"client {client}'s requests out of its order"
        taken[client] += 1
        matched.append((sent, when))
    return matched


def overtakings(matched: list[tuple[Sent, float]], heads) -> list[str]:
    """Requests on the line before a request of another client that surely arrived before
    them, that one being at the head of its client's queue then (heads(sent): from when it
    was; None: never judged).  A closed-loop client's request is at its head once sent, but
    for its first: connect() returns when the kernel has the connection, and the gateway may
    accept it (and see that request) only after other clients' requests that came later."""
    found = []
    for i, (late, _) in enumerate(matched):
        for early, _ in matched[i + 1:]:
            head = heads(early)
            if early.client != late.client and head is not None and late.before > head:
                found.append(f"client {late.client} #{late.number} (sent at "
                             f"{late.before:.4f}) went before client {early.client} "
                             f"#{early.number} (waiting since {head:.4f})")
    return found


def most_waited_through(matched: list[tuple[Sent, float]], heads) -> dict[int, int]:
    """For each other client, the most of its requests that reached the line while one
    request was waiting at the head of its queue (heads as for overtakings)."""
    most: dict[int, int] = {}
    for i, (sent, _) in enumerate(matched):
        head = heads(sent)
        if head is None:
            continue
        counts: dict[int, int] = {}
        for other, when in matched[:i]:
            if other.client != sent.client and when > head:
                counts[other.client] = counts.get(other.client, 0) + 1
        for client, n in counts.items():
            most[client] = max(most.get(client, 0), n)
    return most


@pytest.fixture
def rig(pty_pair, start_gateway, recording_peer, shortcut_both_ways):
    """(gateway, the slave's record): stout STOUT_MS, 0x0B for the silent unit at once, so
    its client asks again at once; demotion off, so that the silent unit stays on the line
    (tests/integration/slave/test_demotion.py has it on); no late window, whose wait after a
    timeout lets other units' requests go first on purpose (tests/integration/slave/test_faults.py
    has it)."""
    record = recording_peer("fault_slave.py")
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--stout", str(STOUT_MS),
                       "--exception", "--max-connections", "40", "--down-after", "0",
                       "--late-window", "0", *shortcut_both_ways)
    return gw, record


def test_no_request_is_overtaken_by_a_later_one_with_a_silent_unit_on_the_line(rig):
    """The issue's case: four clients read unit 1 while a fifth reads a silent unit.  The
    silent unit's client connects first (the lowest fd, read first in a batch): before the
    fix, its fresh request, read in the same poll as one that had waited through its whole
    timeout, went first, and that one waited through a second timeout."""
    gw, record = rig
    clients = [LoopClient(0, SILENT, gw.port)]
    clients += [LoopClient(i, HEALTHY, gw.port) for i in range(1, 5)]
    log = run_loop(clients, RUN_S)
    matched = on_the_line(log, line_order(record))
    silent = sum(1 for sent, _ in matched if sent.client == 0)
    assert silent >= 5, f"the silent unit was asked only {silent} times"
    closed_loop = lambda sent: sent.after if sent.number else None      # noqa: E731
    assert overtakings(matched, closed_loop) == []
    assert set(most_waited_through(matched, closed_loop).values()) <= {1}


def test_a_pipelining_client_gets_one_turn_per_round(rig):
    """A client that keeps several requests queued beside closed-loop clients: each
    closed-loop request waits for at most one of the pipelining client's transactions.
    Before the fix, a client with requests left went back into the ring before the requests
    that had arrived during its transaction were read, so it was served twice ahead of
    them."""
    gw, record = rig
    clients = [LoopClient(1, HEALTHY, gw.port, pipeline=8)]
    clients += [LoopClient(i, HEALTHY, gw.port) for i in range(2, 5)]
    log = run_loop(clients, RUN_S)
    matched = on_the_line(log, line_order(record))
    assert sum(1 for sent, _ in matched if sent.client == 1) >= 100
    closed_loop = lambda sent: sent.after if sent.client != 1 and sent.number else None  # noqa
    assert overtakings(matched, closed_loop) == []
    assert set(most_waited_through(matched, closed_loop).values()) <= {1}
