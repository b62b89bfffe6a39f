"""The line thread's side of slave mode's Modbus TCP connections: one poll() over the
clients, the serial port and the wake-up eventfd.

The asyncio thread accepts and admits a connection, then adopts it here.  From then on the
line thread reads it, frames the requests and hands each to on_request; replies are written
with Client.send.  A request that arrives on an idle line thus wakes one thread, which puts
it on the line at once.  A connection that ends, breaks or sends a bad MBAP header is closed
here, and on_closed is told.
"""
import logging
import os
import select
import time
from collections import deque
from collections.abc import Callable

from mbgw.errors import BadHeader
from mbgw.line.native import ClientReader
from mbgw.ops.limits import WarnLimit
from mbgw.slave.client import RECEIVE_SIZE, Client

log = logging.getLogger("mbgw.tcp")

_IN = select.POLLIN
_OUT = select.POLLOUT


class Connections:
    def __init__(self, wake_fd: int, on_request, on_closed, counters) -> None:
        self._wake_fd = wake_fd
        self._on_request = on_request      # on_request(client, tid, unit, pdu), line thread
        self._on_closed = on_closed        # on_closed(client), line thread
        self._counters = counters
        self._poll = select.poll()
        self._poll.register(wake_fd, _IN)
        self._clients: dict[int, Client] = {}      # by fd
        self._events: dict[int, int] = {}          # what each client's fd is polled for
        self._adopted: deque[Client] = deque()     # from the asyncio thread, not yet polled
        self._reader = ClientReader(RECEIVE_SIZE)
        self._also: dict = {}                      # fd -> on_ready (poll_also)
        self._again: list[Client] = []   # whole requests held, room again: served unpolled
        # the clients whose readability or output may have changed since update() (told by
        # Client.on_change), so that no wait scans them all
        self._changes: list[Client] = []
        self._mirror: select.poll | None = None    # the table reader's poll (attach)
        self._warn = WarnLimit(log)
        # called when the wake-up eventfd is read (by whoever holds the gate)
        self.on_wake: Callable[[], None] | None = None

    def adopt(self, client: Client) -> None:
        """Asyncio thread: from now on the line thread serves client."""
        self._adopted.append(client)
        os.eventfd_write(self._wake_fd, 1)

    def poll_also(self, fd: int, on_ready) -> None:
        """Line thread: fd wakes wait() too, which then calls on_ready() (the scenario
        engine's eventfd; its owner reads it)."""
        self._poll.register(fd, _IN)
        self._also[fd] = on_ready

    def wait(self, timeout_ms: int, serial_fd: int = -1, take=None) -> bool:
        """Line thread: wait up to timeout_ms (-1: no limit, 0: not at all) for a client, the
        wake-up eventfd or input on serial_fd, and serve the clients that are ready.  True
        when serial_fd has input (or an error) waiting.  take(client): reads a client at
        rest in its own way when it is all that is ready (the line worker's shortcut: with
        more, which came first is told by reading them all), and returns what
        Client.receive would."""
        self.update()
        if serial_fd >= 0:
            self._poll.register(serial_fd, _IN)
        again = self._again
        try:
            ready = self._poll.poll(0 if again else timeout_ms)
        finally:
            if serial_fd >= 0:
                self._poll.unregister(serial_fd)
        if again:
            ready = self._with_held(ready, again)
        serial = False
        if len(ready) != 1:
            take = None         # input on the line (it is not quiet), or several ready
        for fd, events in ready:
            if fd == serial_fd:
                serial = True
            elif fd == self._wake_fd:
                self._woken()
            else:
                client = self._clients.get(fd)
                if client is None:
                    if fd in self._also:
                        self._also[fd]()
                    continue
                if take is not None and client.at_rest and client.guard is None:
                    self._serve(client, events, take)
                    take = None
                else:
                    self._serve(client, events)
        return serial

    def _with_held(self, ready: list, again: list[Client]) -> list:
        """ready, and the clients whose held requests may go on now (as if they had input)."""
        polled = {fd for fd, _ in ready}
        for client in again:
            if client.fd not in polled:
                polled.add(client.fd)
                ready.append((client.fd, _IN))
        again.clear()
        return ready

    # --- the table reader (mbgw.slave.table_reader), under the line worker's gate ---

    def attach(self, poll: select.poll) -> None:
        """From now on poll (the table reader's) has every client that may be read now,
        for input, as this thread's own poll has them."""
        self.update()
        for fd, events in self._events.items():
            if events & _IN:
                poll.register(fd, _IN)
        self._mirror = poll

    def detach(self) -> None:
        self._mirror = None

    def serve_ready(self, ready, on_request) -> None:
        """Serve what the table reader's poll() found ready (it polled without the gate: a
        client may have been closed since, its fd even reused, or read by the line thread),
        each request to on_request(client, tid, unit, pdu)."""
        for fd, events in ready:
            if fd == self._wake_fd:
                self._woken(on_request)
                continue
            client = self._clients.get(fd)
            if client is not None and client.readable:
                self._serve(client, events & ~_OUT, on_request=on_request)

    def close_all(self) -> None:
        while self._adopted:
            self._adopted.popleft().close()
        for client in list(self._clients.values()):
            self._close(client)

    def _woken(self, on_request=None) -> None:
        try:
            os.eventfd_read(self._wake_fd)
        except BlockingIOError:
            pass
        if self.on_wake is not None:
            self.on_wake()
        while self._adopted:
            # read at once: what a newcomer sent must not wait for the next transaction
            client = self._adopted.popleft()
            self._clients[client.fd] = client
            self._events[client.fd] = _IN
            self._poll.register(client.fd, _IN)
            if self._mirror is not None:
                self._mirror.register(client.fd, _IN)
            client.polled_in = True
            client.on_change = self._changes.append
            self._changes.append(client)    # looked at in the next update(), once
            self._serve(client, _IN, on_request=on_request)

    def update(self) -> None:
        """Under the gate: poll each client that changed for what it can take now: no
        input while it has 16 requests in the gateway or a backlog of replies it does not
        read.  What a client held back so sent meanwhile is in the line's order from when it
        is read again."""
        changes = self._changes
        if not changes:
            return
        clients = self._clients
        for client in changes:
            client.changed = False
            fd = client.fd
            if clients.get(fd) is not client:
                continue
            readable = client.readable
            if readable and client.held:
                self._again.append(client)
            wanted = (_IN if readable else 0) | (_OUT if client.output_waiting else 0)
            polled = self._events[fd]
            if wanted == polled:
                continue
            if not wanted:
                self._poll.unregister(fd)
            elif polled:
                self._poll.modify(fd, wanted)
            else:
                self._poll.register(fd, wanted)
            self._events[fd] = wanted
            if (wanted ^ polled) & _IN:
                self._polled_in(client, bool(wanted & _IN))
        changes.clear()

    def _polled_in(self, client: Client, polled: bool) -> None:
        client.polled_in = polled
        if polled:
            client.resumed_ns = time.monotonic_ns()
        mirror = self._mirror
        if mirror is not None:
            if polled:
                mirror.register(client.fd, _IN)
            else:
                mirror.unregister(client.fd)

    def _serve(self, client: Client, events: int, take=None, on_request=None) -> None:
        if events & _OUT:
            client.flush()
            if not client.changed:
                client.changed = True
                self._changes.append(client)
        if not events & ~_OUT:
            return
        on_request = on_request or self._on_request
        try:
            frames = client.receive(self._reader) if take is None else take(client)
        except BadHeader as err:
            self._counters.connections_bad_header += 1
            self._warn.warn(client.host, "bad header", "client %s: bad MBAP header (%s); "
                            "closing the connection", client.peer, err)
            self._close(client)
            return
        if frames is None:
            self._close(client)
            return
        try:
            for tid, unit, request in frames:
                on_request(client, tid, unit, request)
        except Exception:   # a bug must cost one connection, never the line
            log.exception("internal error on a request of client %s; closing it", client.peer)
            self._close(client)

    def _close(self, client: Client) -> None:
        fd = client.fd
        events = self._events.pop(fd, 0)
        if events:
            self._poll.unregister(fd)
        if events & _IN and self._mirror is not None:
            self._mirror.unregister(fd)
        client.on_change = None          # nothing of it to update any more
        client.changed = True
        del self._clients[fd]
        client.close()
        self._on_closed(client)
