"""The queue in front of the serial line: fair between clients, in order within a client.

Each client (a TCP connection) has its own FIFO; the line takes one request from each client
in turn, so a client that pipelines many requests cannot starve the others.  Only the line
thread submits and takes; other threads wake it through wake_fd (a new connection, new
settings, stopping).
"""
import os
from collections import deque


class Job:
    __slots__ = ("client", "tid", "unit", "adu", "outcome", "received_ns", "probe")

    def __init__(self, client, tid: int, unit: int, adu: bytes, received_ns: int = 0,
                 probe: bool = False) -> None:
        self.client = client
        self.tid = tid
        self.unit = unit
        self.adu = adu
        self.outcome = ""          # set by the line thread: one of the OUTCOME_* strings
        self.received_ns = received_ns
        self.probe = probe         # admitted while its address is down: it goes on the line


OUTCOME_REPLY = "reply"
OUTCOME_EXCEPTION = "device exception"
OUTCOME_TIMEOUT = "timeout"
OUTCOME_LINE_DOWN = "line down"
OUTCOME_DEVICE_DOWN = "device down"    # refused: its address is down, and it is no probe
OUTCOME_BROADCAST = "broadcast"
OUTCOME_UNROUTABLE = "unroutable"
OUTCOME_ERROR = "internal error"


class Queue:
    """One client's pending jobs."""
    __slots__ = ("jobs", "scheduled")

    def __init__(self) -> None:
        self.jobs: deque[Job] = deque()
        self.scheduled = False


class Scheduler:
    def __init__(self) -> None:
        self._ring: deque[Queue] = deque()
        self.depth = 0              # jobs waiting, for status and metrics
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)

    def submit(self, queue: Queue, job: Job) -> None:
        queue.jobs.append(job)
        self.depth += 1
        if not queue.scheduled:
            queue.scheduled = True
            self._ring.append(queue)

    def take(self) -> Job | None:
        """The next job, round-robin over clients; None if none waits."""
        if not self._ring:
            return None
        queue = self._ring.popleft()
        job = queue.jobs.popleft()
        self.depth -= 1
        if queue.jobs:
            self._ring.append(queue)
        else:
            queue.scheduled = False
        return job

    def discard(self, queue: Queue) -> None:
        """Forget a client's pending jobs (it disconnected)."""
        self.depth -= len(queue.jobs)
        queue.jobs.clear()
        if queue.scheduled:
            queue.scheduled = False
            self._ring.remove(queue)

    def wake(self) -> None:
        """From another thread: the line thread looks at its flags again."""
        os.eventfd_write(self.wake_fd, 1)

    def close(self) -> None:
        os.close(self.wake_fd)
