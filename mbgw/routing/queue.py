"""A request handed to a target on another thread, and its turn there.

A face builds an `Exchange` and submits it to the target's `Inbox`; the target's thread
drains the inbox and answers each exchange through its `done`.  A line's thread first lines
it up in its `Scheduler` (a turn per source, beside the line's own clients and scenarios); a
server's thread serves them in order.  A face whose thread waits for the answer itself (a
serial face) does so with an `AnswerWait`.
"""
import os
import select
import time
from collections import deque
from collections.abc import Callable, Hashable
from typing import Any

from mbgw.config.cache import CacheRule, RouteCache
from mbgw.errors import Interrupted
from mbgw.ops.eventfd import drain

# --- the hand-over: an exchange, the target's inbox ---

# done(exchange, reply, outcome): called once, on the target's thread.  reply is the PDU
# answered (an exception reply included), or None when nothing is to be sent (a broadcast,
# or silence where `exception` is off).  outcome is the trace's word for what happened.
Done = Callable[["Exchange", "bytes | None", str], None]


class Exchange:
    """What a face hands a target: the address on the target (the unit after the route's
    rewrite), the PDU, when it arrived, who is owed the answer."""
    __slots__ = ("source", "address", "pdu", "received_ns", "done", "context", "cache",
                 "loan_to", "taken", "forwarded")

    def __init__(self, source: Hashable, address: int, pdu: bytes, received_ns: int,
                 done: Done, context: object = None,
                 cache: RouteCache = None) -> None:
        self.source = source          # fairness: one turn in the target's ring per source
        self.address = address        # serial address (line) or unit id (server)
        self.pdu = pdu
        self.received_ns = received_ns
        self.done = done
        self.context = context        # the face's own (its client, tid, unit): never read here
        self.cache = cache            # its route's cache (None: the line's, False: off)
        # a target that may take the client's next requests itself (mbgw.slave.loans.Loans)
        self.loan_to: Any = None
        self.taken = False            # read by that target from a lent client, not the face
        self.forwarded = -1           # the bytes of its reply the target sent the client


class SurveyRead(Exchange):
    """An operator's commissioning read (`mbgw scan`/`probe --line`): one request on the
    line in its source's turn, outside the line's rules (no retries, no demotion, no books),
    with a timeout of its own; the target sets response_ns before done."""
    __slots__ = ("timeout_ms", "response_ns")

    def __init__(self, source: Hashable, address: int, pdu: bytes, received_ns: int,
                 done: Done, timeout_ms: int) -> None:
        super().__init__(source, address, pdu, received_ns, done)
        self.timeout_ms = timeout_ms
        self.response_ns = 0      # from the request's last byte to the reply's last byte


class Inbox:
    """The way into a target's thread: exchanges submitted by other threads, in order;
    wake_fd becomes readable while some wait (the target's thread polls it)."""

    def __init__(self) -> None:
        self._waiting: deque[Exchange] = deque()     # deque's append/popleft: thread-safe
        self.loans: Any = None     # its target's, if it takes lent clients (mbgw.slave.loans)
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)

    def submit(self, exchange: Exchange) -> None:
        """Any thread."""
        self._waiting.append(exchange)
        os.eventfd_write(self.wake_fd, 1)

    @property
    def waiting(self) -> bool:
        """Something was submitted since the last drain."""
        return bool(self._waiting)

    def drain(self) -> list[Exchange]:
        """The target's thread: what was submitted since the last drain."""
        drain(self.wake_fd)
        waiting = self._waiting
        taken = []
        while waiting:
            taken.append(waiting.popleft())
        return taken

    def close(self) -> None:
        os.close(self.wake_fd)


# --- a line's turns: the queue in front of the serial line ---

class Job:
    __slots__ = ("client", "tid", "unit", "adu", "outcome", "received_ns", "probe", "exchange",
                 "cache")

    def __init__(self, client, tid: int, unit: int, adu: bytes, received_ns: int = 0,
                 probe: bool = False, exchange: Exchange | None = None,
                 cache: CacheRule | None = None) -> None:
        self.client = client       # None for an exchange (another face's) or a scenario
        self.exchange = exchange   # its done() is told the outcome
        self.tid = tid
        self.unit = unit
        self.adu = adu
        self.outcome: str = ""     # set by the line thread: an ops.trace.Outcome
        self.received_ns = received_ns
        self.probe = probe         # admitted while its address is down: it goes on the line
        self.cache = cache         # a read under a cache rule (mbgw.routing.cache)


# What take() returns for the scenario queue's turn: the line thread runs the scenario due.
SCENARIO_TURN = Job(None, 0, 0, b"")


class Queue:
    """One client's pending jobs, and when its turn began (while it has one)."""
    __slots__ = ("jobs", "scheduled", "turn_ns")

    def __init__(self) -> None:
        self.jobs: deque[Job] = deque()
        self.scheduled = False      # it has a turn: in the ring, or its job on the line
        self.turn_ns = 0


class Scheduler:
    """The queue in front of the serial line: fair between clients, in order within a client.

    Each client (a TCP connection, or a face handing exchanges over) has its own FIFO and,
    while it has requests waiting, one turn in a ring; the line takes the earliest turn, one
    request a turn, so a client that pipelines many requests cannot starve the others.  A turn
    is dated: a client with nothing waiting begins one when its request arrives (the kernel's
    receive timestamp, so requests read together after a transaction keep the order they came
    in); a client with more requests after the one taken begins its next when the line comes
    to take a job again, behind every request that arrived meanwhile.  So no request is
    overtaken by another client's that arrived after it, and besides the transaction on the
    line when it came, each waits for at most one transaction of each other waiting client.
    Only the line thread submits and takes; other threads wake it through wake_fd (a new
    connection, new settings, stopping).

    The serial scenarios (mbgw.scenarios) take turns in the same ring as one more client:
    while one of them is due, the scenario queue has a turn (SCENARIO_TURN), begun when it
    fell due or, after a scenario ran and another is due, when the line comes to take a job
    again -- so the line is shared fairly between the scenario queue and each client.

    A request to an address in its late window (mbgw.slave.transaction) is held: take()
    passes over that turn, which keeps its place, and takes the next turn whose request may
    go, so the line never idles while another address's request waits.
    """

    def __init__(self) -> None:
        self._ring: deque[Queue] = deque()      # turns, by turn_ns
        self._continuing: Queue | None = None   # its job is on the line, more wait behind it
        self.depth = 0              # jobs waiting, for status and metrics
        self._scenarios = Queue()   # the scenario queue's turn, while one is due
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)

    def submit(self, queue: Queue, job: Job) -> None:
        """job (which arrived at job.received_ns) behind the client's others."""
        queue.jobs.append(job)
        self.depth += 1
        if not queue.scheduled:
            queue.scheduled = True
            self._line_up(queue, job.received_ns)

    def take(self, held=None) -> Job | None:
        """The job of the earliest turn; None if none waits.  held(address): a request to
        that address must wait, so its turn is passed over (None: none is held).  The line is
        free: the client served last, if it has more, lines up again now."""
        if self._continuing is not None:
            self._line_up(self._continuing, time.monotonic_ns())
            self._continuing = None
        ring = self._ring
        if not ring:
            return None
        if held is None:
            queue = ring.popleft()
        else:
            for queue in ring:
                first = queue.jobs[0]
                if first is SCENARIO_TURN or not held(first.adu[0]):
                    break
            else:
                return None
            ring.remove(queue)
        job = queue.jobs.popleft()
        if job is SCENARIO_TURN:
            queue.scheduled = False
            return job
        self.depth -= 1
        if queue.jobs:
            self._continuing = queue
        else:
            queue.scheduled = False
        return job

    def scenario_due(self, turn_ns: int) -> None:
        """A scenario is due (since turn_ns at the latest): the scenario queue gets a turn
        unless it has one."""
        queue = self._scenarios
        if not queue.scheduled:
            queue.scheduled = True
            queue.jobs.append(SCENARIO_TURN)
            self._line_up(queue, turn_ns)

    def discard(self, queue: Queue) -> None:
        """Forget a client's pending jobs (it disconnected)."""
        self.depth -= len(queue.jobs)
        queue.jobs.clear()
        if queue.scheduled:
            queue.scheduled = False
            if queue is self._continuing:
                self._continuing = None
            else:
                self._ring.remove(queue)

    def _line_up(self, queue: Queue, turn_ns: int) -> None:
        """queue's turn into the ring, behind every turn that began no later: usually at the
        back; a request read late (after a transaction) goes before those that arrived after
        it."""
        queue.turn_ns = turn_ns
        ring = self._ring
        at = len(ring)
        while at and ring[at - 1].turn_ns > turn_ns:
            at -= 1
        ring.insert(at, queue)

    def wake(self) -> None:
        """From another thread: the line thread looks at its flags again."""
        os.eventfd_write(self.wake_fd, 1)

    def close(self) -> None:
        os.close(self.wake_fd)


# --- a face waiting on its own thread for a target's answer ---

class AnswerWait:
    """A face's thread handing exchanges to a target (a serial face's to a line in slave mode)
    and waiting for each answer, which `done` hands over from the target's thread.

    The wait also watches the face's own eventfd, so that stopping ends it at once (a new
    configuration is taken after the request).  The target always answers; a safety deadline
    still bounds the wait (the face answers 0x0B).  An answer that comes after its deadline
    is dropped at the next wait, never taken for a later request's."""

    def __init__(self, source: str, wake_fd: int, stopping: Callable[[], bool]) -> None:
        """source: the face's name (its turn in the target's round robin); wake_fd and
        stopping(): the face thread's wake-up and whether it is stopping."""
        self._source = source
        self._wake_fd = wake_fd
        self._stopping = stopping
        self._fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._answered: deque[tuple[Exchange, bytes | None, str]] = deque()

    def ask(self, inbox: Inbox, address: int, request: bytes, received_ns: int,
            deadline_ns: int, cache: RouteCache = None
            ) -> tuple[bytes | None, str] | None:
        """The target's (reply PDU or None for silence, outcome) to the request PDU for the
        address there; None when it has not answered by deadline_ns.  cache: the route's
        (Exchange.cache).  Raises Interrupted."""
        exchange = Exchange(self._source, address, request, received_ns, self._done,
                            cache=cache)
        inbox.submit(exchange)
        while True:
            while self._answered:
                done, reply, outcome = self._answered.popleft()
                if done is exchange:
                    return reply, outcome
            timeout_s = (deadline_ns - time.monotonic_ns()) / 1e9
            if timeout_s <= 0:
                return None
            ready = select.select([self._fd, self._wake_fd], [], [], timeout_s)[0]
            if self._wake_fd in ready:
                if self._stopping():
                    raise Interrupted()
                drain(self._wake_fd)        # a new configuration: applied after this
            if self._fd in ready:
                drain(self._fd)

    def _done(self, exchange: Exchange, reply: bytes | None, outcome: str) -> None:
        """The target's thread: its answer to one of our exchanges."""
        self._answered.append((exchange, reply, outcome))
        os.eventfd_write(self._fd, 1)

    def close(self) -> None:
        """After the face's thread has ended."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
