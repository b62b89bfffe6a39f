"""`raw-port`: one TCP client at a time gets the line as a byte stream (as ser2net gives it):
what it sends goes to the line, the frames the line brings go to it.  Served by the line
thread's poll(); a second client is refused (logged once a minute per address); authip
applies.  An accept() that fails for want of descriptors rests the listener (it never
spins): resting_until, which the line thread's poll() timeout serves."""
import logging
import select
import socket
import time

from mbgw.audit import Kind
from mbgw.net.address import format_address
from mbgw.ops.limits import AcceptRest, WarnLimit, is_resource_error
from mbgw.transparent.counters import TransparentCounters

log = logging.getLogger("mbgw.transparent")

RECEIVE_SIZE = 4096


class RawPort:
    """The listening sockets and the one client, in the line thread's poll (attach())."""

    def __init__(self, listeners: list[socket.socket], allows,
                 counters: TransparentCounters) -> None:
        self.listeners = {s.fileno(): s for s in listeners}
        self._poll: select.poll | None = None
        self.allows = allows
        self.client: socket.socket | None = None
        self.peer = ""
        self.reading = False            # the client may still send (no EOF from it yet)
        self._counters = counters
        self._warn = WarnLimit(log)
        self._rest = AcceptRest(log, "raw port")
        self._resting: list[int] = []       # listeners' fds out of the poll meanwhile
        self.resting_until: float | None = None

    def attach(self, poll: select.poll) -> None:
        """Be served by this poll: the listeners and the client while it sends are in it."""
        self._poll = poll
        for fd in self.listeners:
            poll.register(fd, select.POLLIN)

    def is_client(self, fd: int) -> bool:
        return self.client is not None and fd == self.client.fileno()

    @property
    def port(self) -> int:
        return next(iter(self.listeners.values())).getsockname()[1]

    def accept(self, fd: int) -> None:
        """A new client on listener fd, unless it is refused."""
        try:
            sock, address = self.listeners[fd].accept()
        except OSError as err:
            if is_resource_error(err) and self._poll is not None:
                self._poll.unregister(fd)
                self._resting.append(fd)
                self.resting_until = time.monotonic() + self._rest.failed(err)
            return
        self._rest.accepted()
        peer = format_address(address)
        if not self.allows(address[0]):
            key, reason = "authip", "not in authip"
        elif self.client is not None and self.reading:
            key, reason = "busy", f"{self.peer} has the raw port (one client at a time)"
        else:
            if self.client is not None:
                log.info("raw client %s, done sending, gives way to %s", self.peer, peer)
                self.drop()
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.client, self.peer, self.reading = sock, peer, True
            if self._poll is not None:
                self._poll.register(sock.fileno(), select.POLLIN)
            log.info("raw client %s connected", peer)
            return
        sock.close()
        self._counters.raw_refused += 1
        self._warn.warn(address[0], key, "raw client %s refused: %s", peer, reason,
                        kind=Kind.CONNECTION_REFUSED, client=peer, reason=reason)

    def wake_up(self, now: float) -> None:
        """The line thread's turn: listeners that have rested listen again."""
        if self.resting_until is not None and now >= self.resting_until:
            self.resting_until = None
            assert self._poll is not None
            for fd in self._resting:
                self._poll.register(fd, select.POLLIN)
            self._resting.clear()

    def receive(self) -> bytes | None:
        """What the client sent: None for nothing now, b"" when it will send no more (then
        poll it no more).  A client that has shut down its sending side (`socat -t`) still
        gets the frames, until it goes or another client comes."""
        assert self.client is not None
        try:
            data = self.client.recv(RECEIVE_SIZE)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError:
            self.drop()
            return b""
        if not data:
            self._stop_reading()
        return data

    def ended(self) -> None:
        """poll() says the client that was done sending is gone (its reset: it had closed,
        and a frame reached it): noticed now, not when a newcomer comes."""
        self.drop()

    def _stop_reading(self) -> None:
        """Done sending: poll it only for its end (no events asked: POLLERR, POLLHUP)."""
        if self.reading and self._poll is not None and self.client is not None:
            self._poll.modify(self.client.fileno(), 0)
        self.reading = False

    def send(self, frame: bytes) -> None:
        """A frame from the line, as much of it as the socket takes now."""
        if self.client is None:
            return
        try:
            sent = self.client.send(frame)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            self.drop()
            return
        self._counters.raw_bytes_out += sent
        self._counters.raw_bytes_dropped += len(frame) - sent

    def drop(self) -> None:
        if self.client is not None:
            if self._poll is not None:
                self._poll.unregister(self.client.fileno())
            self.reading = False
            self.client.close()
            self.client = None
            log.info("raw client %s disconnected", self.peer)

    def close(self) -> None:
        self.drop()
        for sock in self.listeners.values():
            sock.close()
