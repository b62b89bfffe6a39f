"""The Modbus TCP face's connections on the line thread of slave mode: each client's socket,
its reading and framing (`Client`, `TlsClient`), and one poll() over the clients, the serial
port and the wake-up eventfd (`Connections`).

The asyncio thread accepts and admits a connection, then adopts it here.  From then on the
line thread reads it, frames the requests and hands each to on_request; replies are written
with Client.send.  A request that arrives on an idle line thus wakes one thread, which puts
it on the line at once.  A connection that ends, breaks or sends a bad MBAP header is closed
here, and on_closed is told.  The asyncio thread only reads a client's figures, probes it and
may shut it down.
"""
import errno
import itertools
import logging
import os
import select
import socket
import ssl
import threading
import time
from collections import deque
from collections.abc import Callable

from mbgw.errors import BadHeader
from mbgw.firewall.guard import Guard
from mbgw.line.native import (
    NO_FORWARD,
    ClientReader,
    Forward,
    counter,
    split_frames,
    whole_frame,
)
from mbgw.ops.counters import FaceCounters
from mbgw.ops.eventfd import drain
from mbgw.ops.limits import WarnLimit
from mbgw.routing.queue import Queue

log = logging.getLogger("mbgw.tcp")

MAX_IN_FLIGHT = 16          # TCP guide 4.4.2: a server holds 1..16 transactions per client
RECEIVE_SIZE = 4096         # what one read takes from a connection: 15 requests of 260 bytes
OUTPUT_LIMIT = 65536        # replies held for a client that does not read: then it is not read
_client_ids = itertools.count(1)
# Forward(...) without the NamedTuple's own __new__, a Python call: once per request
_new_tuple = tuple.__new__
# What poll() says of a connection whose peer has closed it or reset it.
PEER_GONE = select.POLLRDHUP | select.POLLHUP | select.POLLERR | select.POLLNVAL
_IN = select.POLLIN
_OUT = select.POLLOUT


class Client:
    """One Modbus TCP connection.  The line thread reads and writes it (Connections); the
    asyncio thread reads its figures and may shut it down."""

    # Who the client is for the firewall (mbgw.firewall): its certificate's role (None on the
    # plain listener) and its listener ("plain" or "tls"); guard: its compiled rule, None when
    # anything goes.
    role: str | None = None
    listener = "plain"
    guard: Guard | None = None
    firewall_refused = 0
    face = FaceCounters()           # its listener's figures (Listener.admit gives them)
    max_in_flight = MAX_IN_FLIGHT
    # Its poller (Connections): on_change(client) when what the client can take may have
    # changed (readable, output_waiting, held); polled_in: whether it is polled for input.
    on_change: Callable[["Client"], None] | None = None
    polled_in = False
    # lent to a remote line's thread (mbgw.slave.loans): read and written there, not here
    lent = False

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
        if flight[0] >= self.max_in_flight and self.polled_in:
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
        return self.in_flight < self.max_in_flight and len(self._out) < OUTPUT_LIMIT

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
                                       max(0, self.max_in_flight - self.in_flight)))
        self.held = whole_frame(buf)
        self._framed(buf, frames, now)
        return frames

    def _framed(self, buf: bytearray, frames: list, now: float) -> None:
        """After received() framed what it could: held told, the partial request dated."""
        if self.held:
            self._changed()
        if not buf or self.held:
            self.partial_since = 0.0
        elif frames or not self.partial_since:
            self.partial_since = now

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


class Connections:
    def __init__(self, wake_fd: int, on_request, on_closed, counters) -> None:
        self._wake_fd = wake_fd
        self._on_request = on_request      # on_request(client, tid, unit, pdu), line thread
        self._on_closed = on_closed        # on_closed(client), line thread
        self._counters = counters
        self._poll = select.poll()
        self._poll.register(wake_fd, _IN)
        # The home: held by the thread that calls wait() (its owner), except while it waits
        # in poll() with nothing to do.  Another thread that has it then may touch the
        # clients in its place (Router._completed): a reply goes out a wake-up sooner.
        self.home = threading.Lock()
        self.home.acquire()
        self._clients: dict[int, Client] = {}      # by fd
        self._events: dict[int, int] = {}          # what each client's fd is polled for
        self._adopted: deque[Client] = deque()     # from the asyncio thread, not yet polled
        self._reader = ClientReader(RECEIVE_SIZE)
        self._also: dict = {}                      # fd -> on_ready (poll_also)
        self._ports: deque = deque()     # the UDP face's sockets (watch), not yet polled
        self._watched: list = []         # those polled
        self._again: list[Client] = []   # whole requests held, room again: served unpolled
        # the clients whose readability or output may have changed since update() (told by
        # Client.on_change), so that no wait scans them all
        self._changes: list[Client] = []
        self._mirror: select.poll | None = None    # the table reader's poll (attach)
        self._warn = WarnLimit(log)
        # called when the wake-up eventfd is read (by whoever holds the gate)
        self.on_wake: Callable[[], None] | None = None
        self._returned: deque[Client] = deque()    # lent clients given back (give_back)
        self.closed = False     # close_all() has closed every client, lent ones included

    def adopt(self, client: Client) -> None:
        """Asyncio thread: from now on the line thread serves client."""
        self._adopted.append(client)
        os.eventfd_write(self._wake_fd, 1)

    def watch(self, port) -> None:
        """Asyncio thread: from now on wait() calls port.ready() when port.fd has input (the
        UDP face's sockets, mbgw.slave.udp_face.UdpPort), until close_all() closes it."""
        self._ports.append(port)
        os.eventfd_write(self._wake_fd, 1)

    def poll_also(self, fd: int, on_ready) -> None:
        """Line thread: fd wakes wait() too, which then calls on_ready() (the scenario
        engine's eventfd, whose owner reads it; a client lent to this line)."""
        self._poll.register(fd, _IN)
        self._also[fd] = on_ready

    def poll_no_more(self, fd: int) -> None:
        """Line thread: poll_also's fd no longer."""
        if self._also.pop(fd, None) is not None:
            self._poll.unregister(fd)

    # --- clients lent to a remote line's thread (mbgw.slave.loans) ---

    def lend(self, client: Client, loans, done) -> None:
        """Under the home: client (at rest, plain) is read and written by loans' line from
        now on, until it gives it back; done: the exchanges' outcomes, as for the face's."""
        fd = client.fd
        events = self._events.get(fd, 0)
        if events:
            self._poll.unregister(fd)
            if events & _IN and self._mirror is not None:
                self._mirror.unregister(fd)
        self._events[fd] = 0
        client.polled_in = False
        client.on_change = None
        client.lent = True
        loans.lend(client, self, done)

    def give_back(self, client: Client) -> None:
        """A lent client's line: the client is this face's again (any thread).  Once the
        face has closed them all (its wake-up eventfd may be closed too), nothing to do."""
        if not self.closed:
            self._returned.append(client)
            os.eventfd_write(self._wake_fd, 1)

    def _take_returned(self) -> None:
        while self._returned:
            client = self._returned.popleft()
            client.lent = False
            if self._clients.get(client.fd) is not client:
                continue                # closed meanwhile (close_all)
            client.on_change = self._changes.append
            client.changed = True
            self._changes.append(client)    # polled again in the next update()

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
        timeout_ms = 0 if again else timeout_ms
        if timeout_ms:
            self.home.release()
        try:
            ready = self._poll.poll(timeout_ms)
        finally:
            if timeout_ms:
                self.home.acquire()
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
                if client.lent:         # polled before it was lent: not ours to read
                    continue
                if take is not None and client.at_rest and client.guard is None:
                    self._serve(client, events, take)
                    take = None
                else:
                    self._serve(client, events)
        return serial

    @property
    def settled(self) -> bool:
        """Under the home: no client has changed since the owner's last poll() began (what
        it polls each for is still right)."""
        return not self._changes

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
            if client is not None and client.readable and not client.lent:
                self._serve(client, events & ~_OUT, on_request=on_request)

    def close_all(self) -> None:
        self.closed = True
        while self._adopted:
            self._adopted.popleft().close()
        self._take_ports()
        for port in self._watched:
            self._poll.unregister(port.fd)
            del self._also[port.fd]
            port.close()
        self._watched.clear()
        for client in list(self._clients.values()):
            self._close(client)

    def _woken(self, on_request=None) -> None:
        drain(self._wake_fd)
        if self.on_wake is not None:
            self.on_wake()
        self._take_returned()
        self._take_ports()
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

    def _take_ports(self) -> None:
        while self._ports:
            port = self._ports.popleft()
            self.poll_also(port.fd, port.ready)
            self._watched.append(port)

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
            if clients.get(fd) is not client or client.lent:
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
