"""The way into a target's thread: any thread submits, the target's thread drains."""
import os
from collections import deque

from mbgw.routing.exchange import Exchange


class Inbox:
    """Exchanges submitted by other threads, in order; wake_fd becomes readable while some
    wait (the target's thread polls it)."""

    def __init__(self) -> None:
        self._waiting: deque[Exchange] = deque()     # deque's append/popleft: thread-safe
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)

    def submit(self, exchange: Exchange) -> None:
        """Any thread."""
        self._waiting.append(exchange)
        os.eventfd_write(self.wake_fd, 1)

    def drain(self) -> list[Exchange]:
        """The target's thread: what was submitted since the last drain."""
        try:
            os.eventfd_read(self.wake_fd)
        except BlockingIOError:
            pass
        waiting = self._waiting
        taken = []
        while waiting:
            taken.append(waiting.popleft())
        return taken

    def close(self) -> None:
        os.close(self.wake_fd)
