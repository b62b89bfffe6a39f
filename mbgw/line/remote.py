"""A line whose device is across the network (`[[line]] connect`): the one socket to it.

At most one connection exists, ever: the device sees one client.  It is opened when a request
needs it (RemoteLine.send), so a connection the device closed is opened again at once by the
next request.  Only a failed attempt (refused, timed out) starts a backoff, BACKOFF_FIRST_S
doubling to BACKOFF_MAX_S, during which requests are refused without trying (`holding`).  The
device is logged once when it is lost and once when it answers again.

Over UDP the socket is connected too, so the kernel drops a datagram from any other address or
port: only the target's can be a reply.  The line thread is the only one to use a RemoteLine.
"""
import errno
import logging
import os
import select
import socket
import time
from typing import Protocol

from mbgw.errors import TargetUnreachable
from mbgw.line.native import BEFORE_UNIT, NO_FORWARD, Forward, MbapExchange

log = logging.getLogger("mbgw.line")

BACKOFF_FIRST_S = 1.0
BACKOFF_MAX_S = 30.0
RECEIVE_SIZE = 4096         # what one read takes from the socket at most


class RemoteCounters(Protocol):
    """What the line and its framing count (mbgw.ops.counters.RemoteCounters)."""
    bytes_sent: int
    bytes_received: int
    noise_bytes: int
    reconnects: int
    stray_replies: int


class RemoteSettings(Protocol):
    @property
    def stout_ms(self) -> int: ...


class RemoteLine:
    """The socket to one remote device (kind: a `connect` scheme, which says TCP or UDP)."""
    libmodbus_sends = False     # the line thread's shortcut is for serial ports only
    char_ns = 0                 # no characters to time on a network

    def __init__(self, name: str, cfg: RemoteSettings, kind: str, host: str, port: int,
                 connect_delay_ms: int, counters: RemoteCounters) -> None:
        self.name = name
        self.cfg = cfg
        self.kind = kind
        self.address = (host, port)
        self.target = f"{kind}://{host}:{port}"
        self.stream = not kind.endswith("-udp")
        self.connect_delay_ms = connect_delay_ms    # a reload may change it
        self.counters = counters
        self.port = self            # what the framing waits on (wait_quiet)
        self.lost = False           # an attempt failed since the device last answered
        self.lost_or_back = time.time()     # when lost last changed (the line's state since)
        self._sock: socket.socket | None = None
        self._readable = select.poll()      # the connection's socket, once there is one
        self._connected = False     # ever: the next connection is a reconnect
        self._retry_at = 0.0        # monotonic: no attempt before then
        self._backoff_s = BACKOFF_FIRST_S
        self._buf = bytearray(RECEIVE_SIZE)
        self._view = memoryview(self._buf)
        self.mbap = MbapExchange()      # Modbus TCP's exchange in C, and what it found

    @property
    def fd(self) -> int:
        """The socket's, for the idle poll(); -1 while there is no connection."""
        return self._sock.fileno() if self._sock is not None else -1

    @property
    def holding(self) -> bool:
        """A failed attempt's backoff holds the next one back: requests get 0x0A at once."""
        return self._sock is None and time.monotonic() < self._retry_at

    def send(self, wire: bytes) -> int:
        """Write wire, connecting first when there is no connection (a write that finds the
        device closed it connects again, once).  Returns when it was written (monotonic ns).
        Raises TargetUnreachable when the device cannot be reached."""
        for _ in range(2):
            sock = self._sock if self._sock is not None else self._connect()
            try:
                if sock.send(wire) < len(wire):     # a full send buffer, never in practice
                    raise BlockingIOError(errno.EAGAIN, "the device does not read")
            except OSError as err:
                self.drop(f"write: {err.strerror or err}")
                continue
            self.counters.bytes_sent += len(wire)
            return time.monotonic_ns()
        raise TargetUnreachable(errno.ECONNRESET, f"{self.target}: the connection closes "
                                                  f"on every write")

    def exchange(self, adu: bytes, tid: int, stout_ns: int,
                 forward: Forward = NO_FORWARD) -> int:
        """Modbus TCP: adu (address + PDU) out with transaction id tid and its reply in, in
        one C call (self.mbap: its result tells what else came), connecting first when
        there is no connection; a request that finds the device closed it goes on a new
        connection, once.  Returns the reply's length (self.mbap.reply()), or -errno when
        none came (a connection that ended, or fell out of step, is dropped); a reply goes
        to forward's client at once (mbap.result.forwarded).  Raises
        TargetUnreachable when the device cannot be reached."""
        mbap = self.mbap
        got = mbap.result
        counters = self.counters
        for _ in range(2):
            sock = self._sock if self._sock is not None else self._connect()
            n = mbap.exchange(sock.fileno(), adu, tid, stout_ns, forward)
            counters.bytes_received += got.stale + got.received
            if got.sent_ns:
                counters.bytes_sent += len(adu) + BEFORE_UNIT
                self.ended(n)
                return n
            self.drop(_ended(n, "write"))
        raise TargetUnreachable(errno.ECONNRESET, f"{self.target}: the connection closes "
                                                  f"on every write")

    def ended(self, n: int) -> None:
        """After a request went out: a connection that n (the C call's result) says ended,
        or fell out of step, is dropped."""
        if n < 0 and n != -errno.ETIMEDOUT:
            self.drop(_ended(n, "read"))

    def not_sent(self, n: int) -> None:
        """A request could not be written (n: the C call's -errno): the connection is over."""
        self.drop(_ended(n, "write"))

    def receive(self, deadline_ns: int) -> memoryview | None:
        """What came next, read before deadline_ns (a datagram whole): a view of this line's
        buffer, valid until the next call.  None: nothing came in time.  Empty: the
        connection ended (closed by the device, reset, or no connection)."""
        n = 0
        while not n:
            sock = self._sock
            if sock is None:
                return self._view[:0]
            left_ns = deadline_ns - time.monotonic_ns()
            if left_ns <= 0 or not self._readable.poll(left_ns / 1e6):     # ms, rounded up
                return None
            try:
                n = sock.recv_into(self._buf)
            except BlockingIOError:
                continue
            except OSError as err:
                self.drop(f"read: {err.strerror or err}")
                return self._view[:0]
            if n == 0 and self.stream:
                self.drop("closed by the device")
                return self._view[:0]
            # n == 0 over UDP: an empty datagram, which is nothing; wait on
        self.counters.bytes_received += n
        return self._view[:n]

    def discard(self) -> int:
        """Take whatever waits to be read, unread (nothing waits: one poll(), no read);
        returns its bytes."""
        discarded = 0
        while self._sock is not None and self._readable.poll(0):
            try:
                n = self._sock.recv_into(self._buf)
            except OSError as err:
                self.drop(f"read: {err.strerror or err}")
                break
            if n == 0 and self.stream:
                self.drop("closed by the device")
                break
            discarded += n
        self.counters.bytes_received += discarded
        return discarded

    def wait_quiet(self, since_ns: int, quiet_us: int) -> int:
        """Let pause pass: nothing is sent before since_ns + quiet_us.  What came meanwhile
        is discarded (returns its bytes): no request is outstanding, so it is no reply."""
        left_s = (since_ns + quiet_us * 1000 - time.monotonic_ns()) / 1e9
        if left_s > 0:
            time.sleep(left_s)
        return self.discard()

    def answered(self) -> None:
        """A valid reply came: a lost device is back."""
        if self.lost:
            self.lost = False
            self.lost_or_back = time.time()
            log.info("line %s: %s answers again", self.name, self.target)

    def drop(self, why: str) -> None:
        """Close the connection (the next request opens another)."""
        if self._sock is not None:
            log.debug("line %s: connection to %s ends: %s", self.name, self.target, why)
            self._sock.close()
            self._sock = None

    def close(self) -> None:
        self.drop("line closed")

    def _connect(self) -> socket.socket:
        if time.monotonic() < self._retry_at:
            raise TargetUnreachable(errno.EHOSTUNREACH, f"{self.target}: unreachable, "
                                                        f"backing off")
        timeout_s = max(self.cfg.stout_ms, 1) / 1000
        try:
            sock = self._open(timeout_s)
        except OSError as err:
            self._failed(err)
            raise TargetUnreachable(err.errno or errno.EHOSTUNREACH,
                                    f"{self.target}: {err.strerror or err}") from None
        sock.setblocking(False)     # its waits are the line's poll(), not a timeout's each
        self._sock = sock
        self._readable = select.poll()
        self._readable.register(sock, select.POLLIN)
        self._backoff_s = BACKOFF_FIRST_S
        if self._connected:
            self.counters.reconnects += 1
        self._connected = True
        if self.stream and self.connect_delay_ms:
            time.sleep(self.connect_delay_ms / 1000)
        return sock

    def _open(self, timeout_s: float) -> socket.socket:
        if self.stream:
            sock = socket.create_connection(self.address, timeout=timeout_s)
            if sock.getsockname() == sock.getpeername():
                # TCP's simultaneous open: a local port nobody listens on, connected to itself
                sock.close()
                raise ConnectionRefusedError(errno.ECONNREFUSED, os.strerror(errno.ECONNREFUSED))
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return sock
        host, port = self.address
        family, kind, proto, _, address = socket.getaddrinfo(host, port,
                                                             type=socket.SOCK_DGRAM)[0]
        sock = socket.socket(family, kind, proto)
        try:
            sock.connect(address)       # datagrams from anywhere else are dropped
        except OSError:
            sock.close()
            raise
        return sock

    def _failed(self, err: OSError) -> None:
        self._retry_at = time.monotonic() + self._backoff_s
        if not self.lost:
            self.lost = True
            self.lost_or_back = time.time()
            log.warning("line %s: %s lost: %s; trying again with backoff up to %g s",
                        self.name, self.target, err.strerror or err, BACKOFF_MAX_S)
        self._backoff_s = min(self._backoff_s * 2, BACKOFF_MAX_S)


def _ended(code: int, doing: str) -> str:
    """Why MbapExchange's -errno code ended the connection (for the debug log)."""
    if code == -errno.ENOTCONN:
        return "closed by the device"
    if code == -errno.EPROTO:
        return "bad MBAP header"
    return f"{doing}: {os.strerror(-code)}"
