"""One Modbus TCP connection of slave mode.  The line thread reads and writes it
(mbgw.slave.connections); the asyncio thread reads its figures and may shut it down."""
import errno
import itertools
import os
import select
import socket
import ssl
import threading
import time
from collections.abc import Callable

from mbgw.firewall.guard import Guard
from mbgw.line.native import (
    NO_FORWARD,
    ClientReader,
    Forward,
    counter,
    split_frames,
    whole_frame,
)
from mbgw.slave.scheduler import Queue

MAX_IN_FLIGHT = 16          # TCP guide 4.4.2: a server holds 1..16 transactions per client
RECEIVE_SIZE = 4096         # what one read takes from a connection: 15 requests of 260 bytes
OUTPUT_LIMIT = 65536        # replies held for a client that does not read: then it is not read
_client_ids = itertools.count(1)
# Forward(...) without the NamedTuple's own __new__, a Python call: once per request
_new_tuple = tuple.__new__
# What poll() says of a connection whose peer has closed it or reset it.
PEER_GONE = select.POLLRDHUP | select.POLLHUP | select.POLLERR | select.POLLNVAL


class Client:
    # Who the client is for the firewall (mbgw.firewall): its certificate's role (None on the
    # plain listener) and its listener ("plain" or "tls"); guard: its compiled rule, None when
    # anything goes.
    role: str | None = None
    listener = "plain"
    guard: Guard | None = None
    firewall_refused = 0
    # Its poller (Connections): on_change(client) when what the client can take may have
    # changed (readable, output_waiting, held); polled_in: whether it is polled for input.
    on_change: Callable[["Client"], None] | None = None
    polled_in = False

    def __init__(self, sock: socket.socket, host: str, peer: str, local: str) -> None:
        self.id = next(_client_ids)
        self.sock = sock
        self.fd = sock.fileno()
        self.host = host
        self.peer = peer
        self.local = local
        self.queue = Queue()
        # requests taken in and not yet answered: C counts one down as it hands a reply over
        self.flight = counter()
        self.requests = 0
        self.connected_at = time.time()
        self.last_active = self.opened = time.monotonic()
        # since when (monotonic s) the request begun in _buf has been waiting for the rest of
        # its bytes; 0.0: none begun (the asyncio thread closes it after request-timeout)
        self.partial_since = 0.0
        self.held = False           # whole requests kept in _buf: 16 in the gateway already
        self.closed = False
        # When the requests last framed arrived (CLOCK_MONOTONIC ns), for the line's order;
        # never before resumed_ns: when the client was last read again after back-pressure.
        self.arrived_ns = 0
        self.resumed_ns = 0
        self._buf = bytearray()     # received, not yet a whole frame
        self._out = bytearray()     # replies the socket would not take yet
        self._lock = threading.Lock()   # close() in the line thread, shutdown() in asyncio's
        self.changed = True         # told to on_change and not looked at since

    @property
    def in_flight(self) -> int:
        """Requests taken in and not yet answered (C's count too: see answered)."""
        return self.flight[0]

    def admitted(self) -> None:
        """A request of this client is in the gateway from now on (queued, kept for the line,
        with another target, or on the line)."""
        flight = self.flight
        flight[0] += 1
        if flight[0] >= MAX_IN_FLIGHT and self.polled_in:
            self._changed()

    def answered(self, forwarded: int = -1) -> None:
        """A request is no longer in the gateway; forwarded: the bytes of its reply C sent
        straight from the line (then C counted it answered as it did), or -1."""
        if forwarded < 0:
            self.flight[0] -= 1
        if not self.polled_in or self.held:     # room again, perhaps
            self._changed()

    def _changed(self) -> None:
        if not self.changed:
            self.changed = True
            if self.on_change is not None:
                self.on_change(self)

    @property
    def readable(self) -> bool:
        return self.in_flight < MAX_IN_FLIGHT and len(self._out) < OUTPUT_LIMIT

    @property
    def output_waiting(self) -> bool:
        return bool(self._out)

    def receive(self, reader: ClientReader) -> list | None:
        """What has arrived, as whole frames [(tid, unit, pdu)], and when (arrived_ns); None
        once the connection has ended.  Raises BadHeader."""
        n = reader.read(self.fd)
        if n == -errno.EAGAIN:
            return self.received(b"", self.arrived_ns) if self.held else []
        if n <= 0:
            return None
        return self.received(reader.data[:n], reader.arrived_ns)

    # C may write a reply to the client's socket itself only while no earlier reply waits
    # here to go out before it (order) and the connection is open: forward_target() for a
    # request from the queue, at_rest for the idle line's shortcut (mbgw_take_request).

    def forward_target(self, tid: int, unit: int, yield_cpu: bool) -> Forward:
        """Where the C receive may send the reply to request tid straight from the line, or
        NO_FORWARD; yield_cpu: nothing else waits for the line, so the client woken by the
        reply may run first."""
        if self._out or self.closed:
            return NO_FORWARD
        return _new_tuple(Forward, (self.fd, tid, unit, yield_cpu, self.flight))

    @property
    def at_rest(self) -> bool:
        """Nothing of this client's in the gateway: no part of a frame, no request, no reply."""
        return not (self._buf or self._out or self.in_flight or self.closed)

    @property
    def busy(self) -> bool:
        """Part of a request read, a request queued or on the line, or replies held for it."""
        return bool(self._buf or self._out or self.in_flight)

    def received(self, data, arrived_ns: int) -> list:
        """What was read from the connection (it arrived at arrived_ns), framed as receive()
        does: as many whole requests as the client may have in the gateway (MAX_IN_FLIGHT),
        the others kept in the buffer (held) until it has room again, so that pipelining
        meets back-pressure however many requests one read brings."""
        buf = self._buf
        buf += data
        self.arrived_ns = max(arrived_ns, self.resumed_ns)
        now = time.monotonic()
        self.last_active = now
        frames = list(itertools.islice(split_frames(buf),
                                       max(0, MAX_IN_FLIGHT - self.in_flight)))
        self.held = whole_frame(buf)
        if self.held:
            self._changed()
        if not buf or self.held:
            self.partial_since = 0.0
        elif frames or not self.partial_since:
            self.partial_since = now
        return frames

    def send(self, frame: bytes) -> None:
        """Onto the socket now, or behind the replies it could not take yet."""
        if not self._out:
            try:
                sent = os.write(self.fd, frame)
            except BlockingIOError:
                sent = 0
            except OSError:
                return                      # the next read finds the connection broken
            if sent == len(frame):
                return
            frame = frame[sent:]
        self._out += frame
        self._changed()

    def flush(self) -> None:
        """Its poller calls it, and looks at the client again after."""
        try:
            sent = os.write(self.fd, self._out)
        except BlockingIOError:
            return
        except OSError:
            self._out.clear()
            return
        del self._out[:sent]

    def probe(self) -> int:
        """Asyncio thread: poll()'s events on the connection now: POLLIN while input waits
        unread, PEER_GONE bits once the peer has closed or reset it (or we closed it)."""
        with self._lock:        # the line thread cannot close the fd, or its number be reused
            if self.closed:
                return select.POLLNVAL
            probe = select.poll()
            probe.register(self.fd, select.POLLIN | select.POLLRDHUP)
            ready = probe.poll(0)
        return ready[0][1] if ready else 0

    def shutdown(self) -> None:
        """Asyncio thread: end the connection; the line thread sees it end and closes it."""
        with self._lock:
            if not self.closed:
                try:
                    self.sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def close(self) -> None:
        with self._lock:
            self.closed = True
            self.sock.close()


class TlsClient(Client):
    """A Modbus/TCP Security connection, its handshake done: read and written through its
    SSLSocket (never by C, which would see the ciphertext: no forward, no shortcut).  Each
    read empties the SSL object, so no decrypted byte waits there unseen by poll()."""
    listener = "tls"

    def __init__(self, sock: ssl.SSLSocket, host: str, peer: str, local: str,
                 role: str | None) -> None:
        super().__init__(sock, host, peer, local)
        self.role = role

    def receive(self, reader: ClientReader) -> list | None:
        sock = self.sock
        assert isinstance(sock, ssl.SSLSocket)
        try:
            data = sock.recv(RECEIVE_SIZE)
            while data and sock.pending():
                data += sock.recv(sock.pending())
        except (ssl.SSLWantReadError, ssl.SSLWantWriteError):
            return self.received(b"", self.arrived_ns) if self.held else []
        except OSError:                 # ssl.SSLError included: the connection is over
            return None
        if not data:
            return None
        return self.received(data, time.monotonic_ns())

    def forward_target(self, tid: int, unit: int, yield_cpu: bool) -> Forward:
        return NO_FORWARD

    @property
    def at_rest(self) -> bool:
        return False                    # never the C shortcut's to read

    def send(self, frame: bytes) -> None:
        if not self._out:
            sent = self._write(frame)
            if sent is None or sent == len(frame):
                return
            frame = frame[sent:]
        self._out += frame
        self._changed()

    def flush(self) -> None:
        sent = self._write(self._out)
        if sent is None:
            self._out.clear()
        else:
            del self._out[:sent]

    def _write(self, data) -> int | None:
        """Bytes taken (0: try again when writable); None once the connection is broken."""
        try:
            return self.sock.send(data)
        except (ssl.SSLWantWriteError, ssl.SSLWantReadError, BlockingIOError):
            return 0
        except OSError:
            return None

    def shutdown(self) -> None:
        """Shut the TCP connection down under the SSL object, which the line thread may be
        using (SSLSocket.shutdown would drop it)."""
        with self._lock:
            if not self.closed:
                try:
                    socket.socket.shutdown(self.sock, socket.SHUT_RDWR)
                except OSError:
                    pass
