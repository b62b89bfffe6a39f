"""The queue in front of the serial line: fair between clients, in order within a client.

Each client (a TCP connection) has its own FIFO and, while it has requests waiting, one turn
in a ring; the line takes the earliest turn, one request a turn, so a client that pipelines
many requests cannot starve the others.  A turn is dated: a client with nothing waiting
begins one when its request arrives (the kernel's receive timestamp, so requests read
together after a transaction keep the order they came in); a client with more requests
after the one taken begins its next when the line comes to take a job again, behind every
request that arrived meanwhile.  So no request is overtaken by another client's that arrived
after it, and besides the transaction on the line when it came, each waits for at most one
transaction of each other waiting client.  Only the
line thread submits and takes; other threads wake it through wake_fd (a new connection, new
settings, stopping).

The serial scenarios (mbgw.scenarios) take turns in the same ring as one more client: while
one of them is due, the scenario queue has a turn (SCENARIO_TURN), begun when it fell due or,
after a scenario ran and another is due, when the line comes to take a job again -- so the
line is shared fairly between the scenario queue and each client.

A request to an address in its late window (mbgw.slave.transaction) is held: take() passes
over that turn, which keeps its place, and takes the next turn whose request may go, so the
line never idles while another address's request waits.
"""
import os
import time
from collections import deque


class Job:
    __slots__ = ("client", "tid", "unit", "adu", "outcome", "received_ns", "probe", "exchange")

    def __init__(self, client, tid: int, unit: int, adu: bytes, received_ns: int = 0,
                 probe: bool = False, exchange=None) -> None:
        self.client = client       # None for an exchange (another face's) or a scenario
        self.exchange = exchange   # a routing.Exchange: its done() is told the outcome
        self.tid = tid
        self.unit = unit
        self.adu = adu
        self.outcome: str = ""     # set by the line thread: an ops.trace.Outcome
        self.received_ns = received_ns
        self.probe = probe         # admitted while its address is down: it goes on the line


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
