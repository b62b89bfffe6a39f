"""Master mode's Modbus TCP server of the exchange table: TCP clients on `table-port` read and
write the registers the serial master reads and writes (VPGate 3.4).

One thread of its own with one poll() over the listening sockets, the connections and a
wake-up eventfd, so a table request never waits for the serial line.  A read takes whatever
the kernel holds (many pipelined requests at once); each whole MBAP frame is answered by one
C call (Table.responder: the frame in, the reply frame out, under the table's lock), and the
replies of one read leave in one send.  Unit id 0 is a broadcast (IDEC): its writes are
done, nothing is sent back.  A protocol id other than 0 or a length outside 2..254 closes
that connection only (counted).  The firewall (mbgw.firewall) compiles each client's rule
when it connects (again at a reload); a request its rule refuses gets 0x01 and never
reaches the table.  A client that does not read its replies is not read either
until the socket has taken them (TCP back-pressure).  At most MAX_CONNECTIONS clients: the
next one is refused (closed at once, counted, logged at most once a minute).  Nothing is
logged per request.
"""
import errno
import logging
import os
import select
import socket
import threading
import time

from mbgw.firewall.guard import Firewall, Guard
from mbgw.protocol import mbap

log = logging.getLogger("mbgw.table")

MAX_CONNECTIONS = 32          # table clients at once (upstream max-connections is another limit)
RECEIVE_SIZE = 4096           # one read: 15 requests of 260 bytes, 341 reads of 12
LISTEN_BACKLOG = 16
REFUSAL_LOG_INTERVAL_S = 60.0
BROADCAST_UNIT = 0

_IN = select.POLLIN
_OUT = select.POLLOUT
_HEADER = mbap.HEADER
_HEADER_LEN = mbap.HEADER_LEN
_MIN_LENGTH = mbap.MIN_LENGTH
_MAX_LENGTH = mbap.MAX_LENGTH
_UNIT_AT = _HEADER_LEN - 1


class TableListenError(OSError):
    """table-port cannot be listened on; the message names the port and why."""

    def __init__(self, port: int, err: OSError) -> None:
        reason = os.strerror(err.errno) if err.errno else str(err)
        super().__init__(err.errno, f"table-port {port}: cannot listen there: {reason}")


def listen(port: int, bind: str | None = None) -> list[socket.socket]:
    """Listening sockets on bind (None: every interface, IPv4 and IPv6) and port.  Raises
    TableListenError."""
    try:
        infos = socket.getaddrinfo(bind, port, socket.AF_UNSPEC, socket.SOCK_STREAM, 0,
                                   socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise TableListenError(port, OSError(0, str(err))) from None
    sockets: list[socket.socket] = []
    try:
        for family, kind, proto, _, address in dict.fromkeys(infos):
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
            sock.listen(LISTEN_BACKLOG)
            sock.setblocking(False)
    except OSError as err:
        for sock in sockets:
            sock.close()
        raise TableListenError(port, err) from None
    return sockets


def _name(address) -> str:
    host, port = address[:2]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class _Connection:
    __slots__ = ("sock", "fd", "peer", "partial", "held", "connected_at", "requests", "host",
                 "role", "listener", "guard", "firewall_refused")

    def __init__(self, sock: socket.socket, peer: str, host: str = "") -> None:
        self.host = host
        self.role: str | None = None        # the firewall's view of it (TLS sets a role)
        self.listener = "plain"
        self.guard: Guard | None = None
        self.firewall_refused = 0
        self.sock = sock
        self.fd = sock.fileno()
        self.peer = peer
        self.partial = bytearray()      # the start of a frame the next read completes
        self.held = bytearray()         # replies the socket has not taken yet
        self.connected_at = time.time()
        self.requests = 0


class TableServer(threading.Thread):
    """The table served on `port`; start() it, stop() and join() it.  figures() and
    connections() may be called from any thread."""

    def __init__(self, table, port: int, bind: str | None = None,
                 firewall: Firewall | None = None, allows=None) -> None:
        """Listens at once: raises TableListenError when it cannot.  allows(host): whether a
        peer may connect (None: anyone; transparent mode's authip)."""
        super().__init__(name="mbgw-table", daemon=True)
        self._table = table
        self.port = port
        self._allows = allows
        self._listeners = listen(port, bind)
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._stopping = False
        self._new_listeners: list[socket.socket] | None = None
        self.firewall = firewall or Firewall(None)
        self._new_firewall: Firewall | None = None
        self._lock = threading.Lock()      # _new_listeners
        self._clients: dict[int, _Connection] = {}
        self._poll = select.poll()
        self._input = bytearray(RECEIVE_SIZE)
        self._input_view = memoryview(self._input)
        self._replies = bytearray()        # the replies of one read, sent together
        self._refused_logged = -REFUSAL_LOG_INTERVAL_S
        self.accepted = 0
        self.refused_limit = 0
        self.bad_header = 0
        self.refused_authip = 0

    @property
    def addresses(self) -> list[str]:
        return [_name(s.getsockname()) for s in self._listeners]

    def figures(self) -> dict:
        """The TCP server's counters, as the status reports them."""
        return {"port": self.port, "connections": len(self._clients),
                "max_connections": MAX_CONNECTIONS,
                "connections_accepted": self.accepted,
                "connections_refused_limit": self.refused_limit,
                "connections_bad_header": self.bad_header,
                "connections_refused_authip": self.refused_authip}

    def connections(self) -> list[dict]:
        return [{"peer": c.peer, "connected": c.connected_at, "requests": c.requests}
                for c in list(self._clients.values())]

    def reset_counts(self) -> None:
        self.accepted = self.refused_limit = self.bad_header = self.refused_authip = 0

    def set_firewall(self, firewall: Firewall) -> None:
        """New rules (another thread): the server's thread guards its clients by them."""
        with self._lock:
            self._new_firewall = firewall
        os.eventfd_write(self._wake_fd, 1)

    def firewall_clients(self) -> list[tuple]:
        """(peer, role, refused) of each client, for the firewall's status."""
        return [(c.peer, c.role, c.firewall_refused) for c in list(self._clients.values())]

    def move(self, port: int, bind: str | None = None) -> None:
        """Listen on port instead (called from another thread; the clients stay).  Raises
        TableListenError, and then the old port stays."""
        listeners = listen(port, bind)
        with self._lock:
            self._new_listeners = listeners
        self.port = port
        os.eventfd_write(self._wake_fd, 1)

    def stop(self) -> None:
        self._stopping = True
        os.eventfd_write(self._wake_fd, 1)

    def run(self) -> None:
        poll = self._poll
        poll.register(self._wake_fd, _IN)
        for sock in self._listeners:
            poll.register(sock.fileno(), _IN)
        listeners = {s.fileno(): s for s in self._listeners}
        clients = self._clients
        answer = self._table.responder().answer_mbap
        try:
            while not self._stopping:
                for fd, events in poll.poll():
                    client = clients.get(fd)
                    if client is not None:
                        self._serve(client, events, answer)
                    elif fd in listeners:
                        self._accept(listeners[fd])
                    elif fd == self._wake_fd:
                        listeners = self._woken(listeners)
        except Exception:
            log.exception("table server: internal error; TCP clients no longer reach the table")
        finally:
            self._close_all()

    # --- connections ---

    def _accept(self, listener: socket.socket) -> None:
        try:
            sock, address = listener.accept()
        except (BlockingIOError, InterruptedError, ConnectionAbortedError):
            return
        except OSError as err:          # out of file descriptors, say: the next one may do
            log.warning("table server: cannot accept a connection: %s", err.strerror)
            return
        if self._allows is not None and not self._allows(address[0]):
            sock.close()
            self.refused_authip += 1
            log.warning("table client %s refused: not in authip", _name(address))
            return
        if len(self._clients) >= MAX_CONNECTIONS:
            sock.close()
            self.refused_limit += 1
            self._log_refusal(address)
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        client = _Connection(sock, _name(address), address[0])
        client.guard = self.firewall.guard(client.host, client.role, client.listener)
        self._clients[client.fd] = client
        self._poll.register(client.fd, _IN)
        self.accepted += 1
        log.debug("table client %s connected", client.peer)

    def _log_refusal(self, address) -> None:
        now = time.monotonic()
        if now - self._refused_logged >= REFUSAL_LOG_INTERVAL_S:
            self._refused_logged = now
            log.warning("table client %s refused: %d table clients are connected, the most "
                        "there may be (further refusals are logged at most once a minute)",
                        _name(address), MAX_CONNECTIONS)

    def _close(self, client: _Connection) -> None:
        del self._clients[client.fd]
        self._poll.unregister(client.fd)
        client.sock.close()
        log.debug("table client %s disconnected", client.peer)

    def _close_all(self) -> None:
        for client in list(self._clients.values()):
            self._close(client)
        for sock in self._listeners:
            sock.close()
        os.close(self._wake_fd)

    def _woken(self, listeners: dict) -> dict:
        try:
            os.eventfd_read(self._wake_fd)
        except BlockingIOError:
            pass
        with self._lock:
            new, self._new_listeners = self._new_listeners, None
            firewall, self._new_firewall = self._new_firewall, None
        if firewall is not None:
            self.firewall = firewall
            for client in self._clients.values():
                client.guard = firewall.guard(client.host, client.role, client.listener)
        if new is None:
            return listeners
        for fd, sock in listeners.items():
            self._poll.unregister(fd)
            sock.close()
        self._listeners = new
        for sock in new:
            self._poll.register(sock.fileno(), _IN)
        log.info("table server: listening on %s", ", ".join(self.addresses))
        return {s.fileno(): s for s in new}

    # --- requests ---

    def _serve(self, client: _Connection, events: int, answer) -> None:
        if events & _OUT:
            if not self._flush(client):
                return
        if not events & (_IN | select.POLLHUP | select.POLLERR):
            return
        try:
            n = client.sock.recv_into(self._input)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._close(client)
            return
        if n == 0:
            self._close(client)
            return
        if client.partial:
            client.partial += self._input_view[:n]
            data = bytes(client.partial)
            client.partial.clear()
            view = memoryview(data)
        else:
            view = self._input_view[:n]
        try:
            self._answer_all(client, view, len(view), answer)
        except mbap.BadHeader as err:
            self.bad_header += 1
            log.warning("table client %s: bad MBAP header (%s); closing the connection",
                        client.peer, err)
            self._close(client)

    def _answer_all(self, client: _Connection, view: memoryview, n: int, answer) -> None:
        """Answer every whole frame in view (n bytes); keep the start of an incomplete one.
        Raises mbap.BadHeader once the replies before the bad header are sent."""
        at = 0
        replies = self._replies
        try:
            while n - at >= _HEADER_LEN:
                _, protocol, length, unit = _HEADER.unpack_from(view, at)
                if protocol != 0:
                    raise mbap.BadHeader(f"protocol id {protocol}")
                if not _MIN_LENGTH <= length <= _MAX_LENGTH:
                    raise mbap.BadHeader(f"length {length}")
                end = at + 6 + length
                if end > n:
                    break
                client.requests += 1
                guard = client.guard
                if guard is not None and not guard.allows(unit, view[at + _HEADER_LEN:end]):
                    reply = self._refused(client, guard, view[at:end], unit)
                else:
                    reply = answer(view[at:end], unit == BROADCAST_UNIT)
                at = end
                if not reply:
                    continue
                if not replies and n - at < _HEADER_LEN:
                    self._send(client, reply)    # alone (the common case): sent as it is
                else:
                    replies += reply             # the buffer is the responder's: copied
        finally:
            if replies:
                self._send(client, replies)
                replies.clear()
        if at < n:
            client.partial += view[at:n]

    def _refused(self, client: _Connection, guard: Guard, frame, unit: int) -> bytes:
        """The reply to a request the firewall refused: 0x01, nothing for a broadcast."""
        client.firewall_refused += 1
        refusal = self.firewall.refused(guard, client.peer, client.role, unit,
                                        frame[_HEADER_LEN:])
        if unit == BROADCAST_UNIT:
            return b""
        return mbap.frame(_HEADER.unpack_from(frame)[0], unit, refusal)

    def _send(self, client: _Connection, data) -> None:
        """Onto the socket now, or held (and the client no longer read) until it takes it."""
        if client.held:
            client.held += data
            return
        try:
            sent = client.sock.send(data)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError as err:
            if err.errno not in (errno.EPIPE, errno.ECONNRESET):
                log.debug("table client %s: send: %s", client.peer, err.strerror)
            return                          # the next poll finds the connection broken
        if sent < len(data):
            client.held += memoryview(data)[sent:]
            self._poll.modify(client.fd, _OUT)

    def _flush(self, client: _Connection) -> bool:
        """Send held replies; True once none are left (the client is read again)."""
        try:
            sent = client.sock.send(client.held)
        except (BlockingIOError, InterruptedError):
            return False
        except OSError:
            self._close(client)
            return False
        del client.held[:sent]
        if client.held:
            return False
        self._poll.modify(client.fd, _IN)
        return True
