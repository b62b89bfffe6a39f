"""The queue in front of the serial line: fair between clients, in order within a client.

Each client (a TCP connection) has its own FIFO; the line takes one request from each client
in turn, so a client that pipelines many requests cannot starve the others.  The asyncio
thread submits, the line thread takes; an eventfd wakes the line thread only when it sleeps.

A request that finds the line thread parked on an idle line, with nothing queued, is put on
the line by the submitting thread itself (the line worker's start_now), and the line thread
is woken to wait for the reply: a request on a quiet line never waits for a thread switch.
"""
import os
import threading
from collections import deque


class Job:
    __slots__ = ("client", "tid", "unit", "adu", "outcome", "received_ns", "started",
                 "start_error")

    def __init__(self, client, tid: int, unit: int, adu: bytes, received_ns: int = 0) -> None:
        self.client = client
        self.tid = tid
        self.unit = unit
        self.adu = adu
        self.outcome = ""          # set by the line thread: one of the OUTCOME_* strings
        self.received_ns = received_ns
        self.started = False       # already on the line: only its reply is still to come
        self.start_error: Exception | None = None    # what putting it on the line raised


OUTCOME_REPLY = "reply"
OUTCOME_EXCEPTION = "device exception"
OUTCOME_TIMEOUT = "timeout"
OUTCOME_LINE_DOWN = "line down"
OUTCOME_BROADCAST = "broadcast"
OUTCOME_UNROUTABLE = "unroutable"
OUTCOME_ERROR = "internal error"


class Queue:
    """One client's pending jobs.  Owned by the scheduler's lock."""
    __slots__ = ("jobs", "scheduled")

    def __init__(self) -> None:
        self.jobs: deque[Job] = deque()
        self.scheduled = False


class Scheduler:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._ring: deque[Queue] = deque()
        self._sleeping = False
        self._parked = False
        self._started: Job | None = None
        self.depth = 0              # jobs waiting, for status and metrics
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        # start_now(job) -> bool: puts job on the line, or declines.  Called with the lock
        # held, only while the line thread is parked.
        self.start_now = lambda job: False

    def submit(self, queue: Queue, job: Job) -> None:
        with self._lock:
            if self._parked and not self._ring and self.start_now(job):
                job.started = True
                self._started = job
                self._parked = self._sleeping = False
                wake = True
            else:
                wake = self._queue(queue, job)
        if wake:
            os.eventfd_write(self.wake_fd, 1)

    def _queue(self, queue: Queue, job: Job) -> bool:
        queue.jobs.append(job)
        self.depth += 1
        if not queue.scheduled:
            queue.scheduled = True
            self._ring.append(queue)
        wake, self._sleeping = self._sleeping, False
        return wake

    @property
    def has_started(self) -> bool:
        """A job submit() put on the line waits for take() (line thread only)."""
        return self._started is not None

    def take(self) -> Job | None:
        """The job submit() started, else the next job, round-robin over clients; None (and
        the line may sleep) if none."""
        with self._lock:
            if self._started is not None:
                job, self._started = self._started, None
                return job
            if not self._ring:
                self._sleeping = True
                return None
            queue = self._ring.popleft()
            job = queue.jobs.popleft()
            self.depth -= 1
            if queue.jobs:
                self._ring.append(queue)
            else:
                queue.scheduled = False
            return job

    def park(self) -> bool:
        """The line thread is about to sleep on an idle line: until unpark(), submit() may
        start a job itself.  False when there is work to take instead."""
        with self._lock:
            if self._ring or self._started is not None:
                return False
            self._parked = True
            return True

    def unpark(self) -> bool:
        """The line thread is awake again; True when submit() started a job meanwhile."""
        with self._lock:
            self._parked = False
            return self._started is not None

    def discard(self, queue: Queue) -> None:
        """Forget a client's pending jobs (it disconnected)."""
        with self._lock:
            self.depth -= len(queue.jobs)
            queue.jobs.clear()
            if queue.scheduled:
                queue.scheduled = False
                self._ring.remove(queue)

    def wake(self) -> None:
        os.eventfd_write(self.wake_fd, 1)

    def close(self) -> None:
        os.close(self.wake_fd)
