"""The pool of Modbus TCP connections to the remote servers (master mode, the TCP scenarios).

One connection per server IP, at most `limit` open: opening one more first closes the least
recently used (TCP guide 4.2.3: "close the oldest unused").  Requests go out in MBAP with a
transaction id of our own, one at a time; only the reply with that id is taken, earlier ones
(late after tcpto) are dropped and counted.  That reply must answer the request: the unit id
sent, the request's function (or its exception) with the size or echo the request implies, a
PDU as long as its MBAP length says (native.tcp_reply_verdict).  One that does not ends the
wait at once as BadReply, since no other reply will come for that id; a bad header (a
protocol id other than 0, a length that does not fit) also closes the connection, whose
stream can no longer be trusted.  A connection the server has closed is found before the
request is sent and reopened; connecting counts against the deadline.

Servers given to set_tls are reached over TLS (Modbus/TCP Security) on its port: the
handshake is stepped in the same non-blocking polls, within the same deadline; a failed one
(a server certificate that does not chain to the CA, that is not for the address dialled
nor the one pinned, our certificate refused) is HandshakeFailed, a NoRoute.

Everything runs on its owner's thread (master mode: the serial line's; the master sends one
request at a time, so a thread hop would only add latency).  The sockets are non-blocking
and every wait is one poll() that the owner's eventfd also wakes, so stopping never waits
for tcpto (a wake for a new configuration does not interrupt the transaction: it is applied
after it).  The status reads connections() from the asyncio thread.
"""
import errno
import logging
import os
import select
import socket
import ssl
import time
from collections import OrderedDict
from collections.abc import Callable

from mbgw.errors import (
    BadHeader,
    BadReply,
    ConnectionLost,
    ConnectTimeout,
    GatewayTimeout,
    HandshakeFailed,
    Interrupted,
    NoRoute,
)
from mbgw.line import native
from mbgw.net.tls import handshake_step, server_mismatch
from mbgw.ops.counters import MasterCounters
from mbgw.ops.eventfd import drain

log = logging.getLogger("mbgw.tcp")
wire = logging.getLogger("mbgw.wire")

RECV_SIZE = 4096
TID_MASK = 0xFFFF


class Connection:
    __slots__ = ("host", "port", "tls", "sock", "poller", "buf", "tid", "local", "connected_at",
                 "last_active", "requests", "units")

    def __init__(self, host: str, port: int, sock: socket.socket, poller) -> None:
        self.host = host
        self.port = port
        self.tls = isinstance(sock, ssl.SSLSocket)
        self.sock = sock
        self.poller = poller
        self.buf = bytearray()
        self.tid = 0
        local = sock.getsockname()
        self.local = f"{local[0]}:{local[1]}"      # mbgw's end
        self.connected_at = time.time()
        self.last_active = time.monotonic()
        self.requests = 0
        self.units: set[int] = set()              # the unit ids it has carried requests for

    def next_tid(self) -> int:
        self.tid = (self.tid + 1) & TID_MASK
        return self.tid


OnSent = Callable[[Connection, int], None]


class UpstreamPool:
    def __init__(self, port: int, limit: int, counters: MasterCounters, wake_fd: int) -> None:
        self._port = port
        self._limit = limit
        self._counters = counters
        self._wake_fd = wake_fd
        self._open: OrderedDict[str, Connection] = OrderedDict()   # least recently used first
        self._failing: set[str] = set()     # servers whose last connection attempt failed
        self._tls: ssl.SSLContext | None = None
        self._tls_port = 0
        self._tls_hosts: frozenset[str] | None = frozenset()   # None: every server
        self._pins: dict[str, bytes] = {}   # servers whose certificate is pinned, by host
        self._chunk = bytearray(RECV_SIZE)
        self._view = memoryview(self._chunk)
        self.stopping = False     # set before the eventfd is signalled to stop
        # (conn, tid, unit, PDU) of a late reply, dropped; for the trace
        self.on_late: Callable[[Connection, int, int, bytes], None] | None = None

    @property
    def port(self) -> int:
        return self._port

    def set_tls(self, context: ssl.SSLContext | None, port: int,
                hosts: frozenset[str] | None, pins: dict[str, bytes] | None = None) -> None:
        """Reach hosts (None: every server) over TLS on port with context; a server's
        certificate must be for the address dialled, or have the SHA-256 pins[host].  Another
        setting closes every connection (on the owner's thread, between transactions)."""
        pins = pins or {}
        if (context, port, hosts, pins) != (self._tls, self._tls_port, self._tls_hosts,
                                            self._pins):
            self.close()
            self._failing.clear()
            self._tls, self._tls_port, self._tls_hosts = context, port, hosts
            self._pins = pins

    def _uses_tls(self, host: str) -> bool:
        return self._tls is not None and (self._tls_hosts is None or host in self._tls_hosts)

    def server(self, host: str) -> str:
        """"host:port" as the pool reaches it (TLS servers on their port)."""
        return f"{host}:{self._tls_port if self._uses_tls(host) else self._port}"

    def reconfigure(self, port: int, limit: int) -> None:
        """New settings, on the line's thread between transactions: another port closes
        every connection; a lower limit closes the least recently used ones over it."""
        if port != self._port:
            self.close()
            self._failing.clear()
            self._port = port
        self._limit = limit
        while len(self._open) > limit:
            _, oldest = self._open.popitem(last=False)
            oldest.sock.close()
            self._counters.connections_evicted += 1

    def connections(self) -> list[dict]:
        """The open connections, least recently used first (from any thread)."""
        for _ in range(3):
            try:
                conns = list(self._open.values())
                break
            except RuntimeError:      # changed by the line thread meanwhile
                continue
        else:
            return []
        now, mono = time.time(), time.monotonic()
        return [{"server": f"{c.host}:{c.port}", "tls": c.tls, "local": c.local,
                 "connected_since": c.connected_at, "requests": c.requests,
                 "units": sorted(c.units), "last_activity": now - (mono - c.last_active)}
                for c in conns]

    def transact(self, host: str, unit: int, request: bytes, deadline_ns: int,
                 on_sent: OnSent | None = None) -> bytes:
        """Send the request PDU to host's unit and return the reply PDU; on_sent(conn, tid)
        once it went out (for the trace).  Raises GatewayTimeout
        when no reply came before deadline_ns (CLOCK_MONOTONIC) or the connection broke
        after the request went out, BadReply when the reply does not answer the request,
        NoRoute when host cannot be reached, Interrupted."""
        conn = self._connection(host, deadline_ns)
        tid = conn.next_tid()
        self._send(conn, native.frame(tid, unit, request), unit)
        if on_sent is not None:
            on_sent(conn, tid)
        while True:
            try:
                for reply_tid, reply_unit, reply in native.split_frames(conn.buf):
                    if reply_tid == tid:
                        conn.last_active = time.monotonic()
                        if wire.isEnabledFor(logging.DEBUG):
                            wire.debug("tcp %s rx tid=%d unit=%d %s", host, tid, reply_unit,
                                       reply.hex(" "))
                        self._check(conn, request, unit, reply_unit, reply)
                        return reply
                    self._late(conn, reply_tid, reply_unit, reply)
            except BadHeader as err:
                reason = f"bad MBAP header: {err}"
                self._bad_header(conn, reason)
                raise BadReply("invalid_frames", reason) from None
            self._wait(conn.poller, deadline_ns)
            if self._receive(conn) is False:
                raise ConnectionLost()

    def send_all(self, hosts, unit: int, request: bytes, deadline_ns: int,
                 on_sent: OnSent | None = None) -> int:
        """Send a request that gets no reply (a broadcast) to each host (on_sent(conn, tid)
        after each); returns how many it reached.  Hosts not connected by deadline_ns are
        skipped.  Raises Interrupted."""
        reached = 0
        for host in hosts:
            try:
                conn = self._connection(host, deadline_ns)
                tid = conn.next_tid()
                self._send(conn, native.frame(tid, unit, request), unit)
            except (GatewayTimeout, NoRoute):
                continue
            if on_sent is not None:
                on_sent(conn, tid)
            reached += 1
        return reached

    def _check(self, conn: Connection, request: bytes, unit: int, reply_unit: int,
               reply: bytes) -> None:
        """Raise BadReply unless reply (from reply_unit) answers request (sent to unit)."""
        verdict = native.tcp_reply_verdict(request, unit, reply_unit, reply)
        if verdict == native.REPLY_ANSWERS:
            return
        if verdict == native.REPLY_BAD_LENGTH:
            reason = (f"bad MBAP header: length {len(reply) + 1} does not fit its function "
                      f"0x{reply[0]:02x} PDU")
            self._bad_header(conn, reason)
            raise BadReply("invalid_frames", reason)
        if verdict == native.REPLY_WRONG_UNIT:
            self._counters.wrong_unit += 1
            raise BadReply("wrong_unit", f"unit id {reply_unit} instead of {unit}", reply_unit,
                           reply)
        self._counters.wrong_function += 1
        function = request[0]
        if reply[0] in (function, function | 0x80):
            reason = f"a function 0x{reply[0]:02x} PDU of {len(reply)} bytes, not the size " \
                     f"or echo the request asks for"
        else:
            reason = f"function 0x{reply[0]:02x} instead of 0x{function:02x}"
        raise BadReply("wrong_function", reason, reply_unit, reply)

    def close(self) -> None:
        for conn in self._open.values():
            conn.sock.close()
        self._open.clear()

    # --- connections ---

    def _connection(self, host: str, deadline_ns: int) -> Connection:
        conn = self._open.get(host)
        if conn is not None:
            self._open.move_to_end(host)
            if self._still_open(conn):
                return conn
        return self._connect(host, deadline_ns)

    def _connect(self, host: str, deadline_ns: int) -> Connection:
        if len(self._open) >= self._limit:
            _, oldest = self._open.popitem(last=False)
            oldest.sock.close()
            self._counters.connections_evicted += 1
            log.debug("server %s:%d: connection closed to make room for %s", oldest.host,
                      oldest.port, host)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET    # an IPv6 literal
        tls = self._uses_tls(host)
        port = self._tls_port if tls else self._port
        sock = socket.socket(family,
                             socket.SOCK_STREAM | socket.SOCK_NONBLOCK | socket.SOCK_CLOEXEC)
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
            poller = select.poll()
            poller.register(sock, select.POLLOUT)
            poller.register(self._wake_fd, select.POLLIN)
            code = sock.connect_ex((host, port))
            if code == errno.EINPROGRESS:
                try:
                    self._wait(poller, deadline_ns)
                except GatewayTimeout:
                    self._failed(host, "no connection within tcpto")
                    raise ConnectTimeout() from None
                code = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            if code:
                self._failed(host, os.strerror(code))
                raise NoRoute(f"{host}:{port}: {os.strerror(code)}")
            if tls:
                assert self._tls is not None
                sock = self._tls.wrap_socket(sock, do_handshake_on_connect=False)
                self._handshake(host, sock, poller, deadline_ns)
            poller.modify(sock, select.POLLIN)
        except BaseException:
            sock.close()
            raise
        conn = Connection(host, port, sock, poller)
        self._open[host] = conn
        self._counters.connections_opened += 1
        if host in self._failing:
            self._failing.discard(host)
            log.info("server %s:%d reachable again", host, port)
        else:
            log.debug("server %s:%d connected%s", host, port, " (TLS)" if tls else "")
        return conn

    def _handshake(self, host: str, sock: ssl.SSLSocket, poller, deadline_ns: int) -> None:
        """The TLS handshake, stepped as the socket is ready, within deadline_ns."""
        while True:
            step, failure = handshake_step(sock, _handshake_failure)
            why: str | None = failure
            if step == "done":
                why = server_mismatch(sock.getpeercert(binary_form=True), host,
                                      self._pins.get(host))
                if why is None:
                    return
            if why:
                self._failed(host, why)
                raise HandshakeFailed(f"{self.server(host)}: {why}")
            poller.modify(sock, select.POLLIN if step == "read" else select.POLLOUT)
            try:
                self._wait(poller, deadline_ns)
            except GatewayTimeout:
                self._failed(host, "no TLS handshake within tcpto")
                raise ConnectTimeout() from None

    def _failed(self, host: str, reason: str) -> None:
        """Report a failed connection attempt once, until the server is reachable again."""
        if host not in self._failing:
            self._failing.add(host)
            log.warning("server %s unreachable: %s", self.server(host), reason)

    def _close(self, conn: Connection) -> None:
        conn.sock.close()
        if self._open.get(conn.host) is conn:
            del self._open[conn.host]

    def _lost(self, conn: Connection, reason: str) -> None:
        self._close(conn)
        self._counters.connections_lost += 1
        log.debug("server %s:%d: connection lost: %s", conn.host, conn.port, reason)

    def _late(self, conn: Connection, tid: int, unit: int, reply: bytes) -> None:
        """A reply to an earlier request (its transaction id): dropped, counted."""
        self._counters.late_replies += 1
        if self.on_late is not None:
            self.on_late(conn, tid, unit, reply)

    def _bad_header(self, conn: Connection, reason: str) -> None:
        """The stream cannot be trusted past a bad header: the next request opens another."""
        self._close(conn)
        self._counters.connections_bad_header += 1
        log.debug("server %s:%d: connection closed: %s", conn.host, conn.port, reason)

    def _still_open(self, conn: Connection) -> bool:
        """Read what came while the connection was idle (late replies, dropped) without
        waiting; False when the server has closed it (it is then dropped)."""
        while got := self._receive(conn):
            try:
                for reply_tid, reply_unit, reply in native.split_frames(conn.buf):
                    self._late(conn, reply_tid, reply_unit, reply)
            except BadHeader as err:
                self._bad_header(conn, f"bad MBAP header ({err})")
                return False
        return got is None

    # --- I/O ---

    def _send(self, conn: Connection, frame: bytes, unit: int) -> None:
        conn.requests += 1
        conn.units.add(unit)
        conn.last_active = time.monotonic()
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("tcp %s tx %s", conn.host, frame.hex(" "))
        try:
            sent = conn.sock.send(frame)
        except OSError as err:
            sent = -1
            reason = err.strerror or str(err)
        else:
            reason = "send buffer full"
        if sent != len(frame):
            self._lost(conn, reason)
            raise ConnectionLost()

    def _receive(self, conn: Connection) -> bool | None:
        """Append what the socket holds to conn.buf: True.  None when nothing was waiting,
        False when the connection was closed or broken (it is then dropped).  A TLS
        connection's records are read whole: poll() does not see what SSL holds decrypted."""
        got = self._receive_once(conn)
        while got and conn.tls and conn.sock.pending():   # type: ignore[attr-defined]
            if (more := self._receive_once(conn)) is not True:
                return False if more is False else got
        return got

    def _receive_once(self, conn: Connection) -> bool | None:
        try:
            n = conn.sock.recv_into(self._chunk)
        except (BlockingIOError, ssl.SSLWantReadError, ssl.SSLWantWriteError):
            return None
        except OSError as err:
            self._lost(conn, err.strerror or str(err))
            return False
        if n == 0:
            self._lost(conn, "closed by the server")
            return False
        conn.buf += self._view[:n]
        return True

    def _wait(self, poller, deadline_ns: int) -> None:
        """Until the socket is ready; raises GatewayTimeout at deadline_ns, Interrupted when
        the eventfd is signalled to stop (another signal, a new configuration, is taken and
        the wait goes on)."""
        while True:
            timeout_ms = -(-(deadline_ns - time.monotonic_ns()) // 1_000_000)
            if timeout_ms <= 0:
                raise GatewayTimeout()
            events = poller.poll(timeout_ms)
            if not events:
                raise GatewayTimeout()
            if not any(fd == self._wake_fd for fd, _ in events):
                return
            if self.stopping:
                raise Interrupted()
            drain(self._wake_fd)
            if len(events) > 1:
                return


def _handshake_failure(err: OSError) -> str:
    """What OpenSSL said, e.g. "TLS handshake failed: the server's certificate: unable to
    get local issuer certificate"."""
    if isinstance(err, ssl.SSLCertVerificationError):
        return f"TLS handshake failed: the server's certificate: {err.verify_message}"
    return f"TLS handshake failed: {getattr(err, 'reason', None) or err}"
