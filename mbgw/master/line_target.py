"""A serial face's side of a request routed to a line in slave mode: the request goes to that
line's thread as an Exchange in its Inbox (mbgw.routing), and the face's thread waits for the
line's answer, which `done` hands over from the line's thread.

The wait also watches the face's own eventfd, so that stopping ends it at once (a new
configuration is taken after the request).  The line always answers; a safety deadline still
bounds the wait (the face answers 0x0B).  An answer that comes after its deadline is dropped
at the next wait, never taken for a later request's."""
import os
import select
import time
from collections import deque
from collections.abc import Callable

from mbgw.errors import Interrupted
from mbgw.routing.exchange import Exchange
from mbgw.routing.inbox import Inbox
from mbgw.upstream.pool import drain


class LineRequests:
    def __init__(self, source: str, wake_fd: int, stopping: Callable[[], bool]) -> None:
        """source: the face's name (its turn in the target line's round robin); wake_fd and
        stopping(): the face thread's wake-up and whether it is stopping."""
        self._source = source
        self._wake_fd = wake_fd
        self._stopping = stopping
        self._fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._answered: deque[tuple[Exchange, bytes | None, str]] = deque()

    def ask(self, inbox: Inbox, address: int, request: bytes, received_ns: int,
            deadline_ns: int) -> tuple[bytes | None, str] | None:
        """The line's (reply PDU or None for silence, outcome) to the request PDU for the
        address there; None when it has not answered by deadline_ns.  Raises Interrupted."""
        exchange = Exchange(self._source, address, request, received_ns, self._done)
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
        """The target line's thread: its answer to one of our exchanges."""
        self._answered.append((exchange, reply, outcome))
        os.eventfd_write(self._fd, 1)

    def close(self) -> None:
        """After the face's thread has ended."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
