"""Master mode's Modbus TCP server of the exchange table: TCP clients on `table-port` read and
write the registers the serial master reads and writes (VPGate 3.4).

One thread of its own with one poll() over the listening sockets, the connections and a
wake-up eventfd, so a table request never waits for the serial line.  What a client sends is
read and answered by mbgw.table.client_requests.  The firewall (mbgw.firewall) compiles each
client's rule when it connects (again at a reload).  At most MAX_CONNECTIONS clients, a
share of them (mbgw.ops.limits.share) from one address: a newcomer over either takes the
place of a client that never sent a whole request or is slow with one, else it is refused
(closed at once, counted, logged at most once a minute per address).  A request begun must be
whole within request_timeout_s, a first request must come within FIRST_REQUEST_S, or the
connection is closed (counted).  An accept() that fails for want of descriptors rests the
listener (it never spins).  Nothing is logged per request.

Modbus/TCP Security (a TLS context given): a TLS listener on `tls_port` beside the plain one
(port None: TLS only).  Each handshake is a state in the same poll loop, stepped when its
socket is ready, never blocking the loop or the plain clients: at most MAX_HANDSHAKES at once,
each with HANDSHAKE_TIMEOUT_S to finish; a refusal is counted and logged at most once a minute.
A TLS client is then served like a plain one through its SSLSocket (its role from the
certificate, for the firewall), and the bytes SSL has decrypted but poll() cannot see
(pending()) are read before the loop waits again.  set_tls() gives new connections a renewed
context; those open keep theirs.
"""
import logging
import os
import queue
import select
import socket
import ssl
import threading
import time

from mbgw.audit import Kind, event
from mbgw.errors import ListenError
from mbgw.firewall.guard import Firewall
from mbgw.net.address import format_address
from mbgw.net.listen import ServerPorts
from mbgw.net.ratelimit import RateLimitedLog
from mbgw.net.tls import HANDSHAKE_TIMEOUT_S, role_of
from mbgw.ops.eventfd import drain
from mbgw.ops.limits import AcceptRest, WarnLimit, share
from mbgw.table.client_requests import ClientRequests
from mbgw.table.connection import Connection, eviction_victim, late
from mbgw.table.handshakes import Handshakes

log = logging.getLogger("mbgw.table")

MAX_CONNECTIONS = 32          # table clients at once, by default ([table] max-connections)
REBIND_WAIT_S = 5.0           # a reload waits this long for the server's thread to rebind
PER_ADDRESS = share(MAX_CONNECTIONS)
SWEEP_S = 0.25                      # how often the deadlines are looked at, with clients

_IN = select.POLLIN


class TableServer(threading.Thread):
    """The table served on `port`; start() it, stop() and join() it.  figures() and
    connections() may be called from any thread."""

    def __init__(self, table, port: int | None, bind: str | None = None,
                 firewall: Firewall | None = None, allows=None,
                 tls: ssl.SSLContext | None = None, tls_port: int | None = None,
                 max_connections: int = MAX_CONNECTIONS,
                 port_option: str = "table-port") -> None:
        """Listens at once: raises ListenError naming port_option (the setting that gives
        port) or tls-port when it cannot.  allows(host): whether a peer may connect (None:
        anyone; authip, mbgw.net.acl.AccessList.allows).  port None: no plain listener;
        tls: the TLS listener's context (mbgw.net.tls.server_context) on tls_port."""
        super().__init__(name="mbgw-table-server", daemon=True)
        self._table = table
        self.max_connections = max_connections     # another thread may set it (a reload)
        self._allows = allows
        self._new_allows: tuple | None = None      # (allows,) from set_access()
        self._new_bind: tuple | None = None        # (bind, queue of the outcome) from rebind()
        self._to_close: list[tuple[int, str]] = []  # (client id, who) from close_client()
        self._last_id = 0
        self._ports = ServerPorts(bind, port, tls_port if tls is not None else None,
                                  option=port_option)
        self._tls = tls
        self._new_tls: tuple | None = None
        self._tls_refusals = RateLimitedLog()       # logged by (address, reason)
        self._answer = None
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._stopping = False
        self._new_listeners: list[socket.socket] | None = None
        self._new_firewall: Firewall | None = None
        self._lock = threading.Lock()      # _new_listeners
        self._clients: dict[int, Connection] = {}
        self._poll = select.poll()
        self._handshakes = Handshakes(self._poll, self._tls_client, self._tls_refused,
                                      self._tls_probe)
        self.accepted = 0
        self.refused_limit = 0
        self.refused_authip = 0
        self.refused_tls = 0
        self.timed_out = 0
        self.evicted = 0
        self.request_timeout_s = HANDSHAKE_TIMEOUT_S     # set by the daemon (request-timeout)
        self._warn = WarnLimit(log)
        self._requests = ClientRequests(self._poll, self._clients, self._close,
                                        firewall or Firewall(None), self._warn)
        self._rest = AcceptRest(log, "table server")
        self._resting: dict[int, float] = {}       # a listener's fd -> when it listens again
        self._swept = 0.0
        self.tls_probes = 0                # closed or reset before a byte: health checks

    @property
    def port(self) -> int | None:
        return self._ports.port

    @property
    def tls_port(self) -> int | None:
        return self._ports.tls_port

    @property
    def bind(self) -> str | None:
        return self._ports.bind

    @property
    def addresses(self) -> list[str]:
        return self._ports.addresses()

    @property
    def firewall(self) -> Firewall:
        """The rules the clients are guarded by (set_firewall gives new ones)."""
        return self._requests.firewall

    def figures(self) -> dict:
        """The TCP server's counters, as the status reports them."""
        return {"port": self.port, "connections": len(self._clients),
                "max_connections": self.max_connections,
                "connections_accepted": self.accepted,
                "connections_refused_limit": self.refused_limit,
                "connections_bad_header": self._requests.bad_header,
                "connections_refused_authip": self.refused_authip,
                "tls_port": self.tls_port, "tls_handshakes": len(self._handshakes),
                "connections_refused_tls": self.refused_tls,
                "connections_timed_out": self.timed_out,
                "connections_evicted": self.evicted,
                "connections_tls_probes": self.tls_probes}

    def connections(self) -> list[dict]:
        return [{"peer": c.peer, "connected": c.connected_at, "requests": c.requests,
                 "listener": c.listener, "role": c.role}
                for c in list(self._clients.values())]

    def clients(self) -> list[dict]:
        """The clients as the status lists them (slave mode's shape: nothing is ever in
        flight, the table answers at once)."""
        now, mono = time.time(), time.monotonic()
        return [{"id": c.id, "peer": c.peer, "connected_since": c.connected_at,
                 "requests": c.requests, "in_flight": 0,
                 "firewall_refused": c.firewall_refused,
                 "last_activity": now - (mono - c.last_active),
                 "listener": c.listener, "role": c.role}
                for c in sorted(list(self._clients.values()), key=lambda c: c.id)]

    def close_client(self, client_id: int, who: str) -> bool:
        """Force-close a client (another thread: the operator's command; who: the operator
        as the log names them); False when there is no such client."""
        if not any(c.id == client_id for c in list(self._clients.values())):
            return False
        with self._lock:
            self._to_close.append((client_id, who))
        os.eventfd_write(self._wake_fd, 1)
        return True

    def reset_counts(self) -> None:
        self.accepted = self.refused_limit = self._requests.bad_header = self.refused_authip = 0
        self.refused_tls = self.timed_out = self.evicted = self.tls_probes = 0

    def set_firewall(self, firewall: Firewall) -> None:
        """New rules (another thread): the server's thread guards its clients by them."""
        with self._lock:
            self._new_firewall = firewall
        os.eventfd_write(self._wake_fd, 1)

    def firewall_clients(self) -> list[tuple]:
        """(peer, role, refused) of each client, for the firewall's status."""
        return [(c.peer, c.role, c.firewall_refused) for c in list(self._clients.values())]

    def set_access(self, allows) -> None:
        """A new authip rule (another thread): the clients it no longer allows are closed."""
        with self._lock:
            self._new_allows = (allows,)
        os.eventfd_write(self._wake_fd, 1)

    def rebind(self, bind: str | None) -> None:
        """Listen on bind instead, on the port and the TLS port (another thread; the clients
        stay).  Raises ListenError, and then the old address stays."""
        outcome: queue.Queue = queue.Queue(maxsize=1)
        with self._lock:
            self._new_bind = (bind, outcome)
        os.eventfd_write(self._wake_fd, 1)
        try:
            error = outcome.get(timeout=REBIND_WAIT_S)
        except queue.Empty:
            error = ListenError("bind", self.port or self.tls_port or 0,
                                "the table server does not answer")
        if error is not None:
            raise error

    def move(self, port: int) -> None:
        """Listen on port instead (called from another thread; the clients stay).  Raises
        ListenError, and then the old port stays."""
        listeners = self._ports.listen_plain(port)
        with self._lock:
            self._new_listeners = listeners
        self._ports.port = port
        os.eventfd_write(self._wake_fd, 1)

    def set_tls(self, context: ssl.SSLContext | None, port: int) -> None:
        """New TLS settings or renewed files (another thread): context (None: TLS off) is for
        new connections, those open keep theirs; listening moves when the port changes.
        Raises ListenError, and then nothing changes."""
        new_port = port if context is not None else None
        listeners = None                    # the same ones
        if new_port != self.tls_port:
            listeners = self._ports.listen_tls(port) if new_port is not None else []
        with self._lock:
            self._new_tls = (context, listeners)
        self._ports.tls_port = new_port
        os.eventfd_write(self._wake_fd, 1)

    def stop(self) -> None:
        self._stopping = True
        os.eventfd_write(self._wake_fd, 1)

    def run(self) -> None:
        poll = self._poll
        poll.register(self._wake_fd, _IN)
        for sock in self._ports.sockets():
            poll.register(sock.fileno(), _IN)
        listeners = self._ports.by_fd()
        clients = self._clients
        handshakes = self._handshakes
        requests = self._requests
        self._answer = answer = self._table.responder().answer_mbap
        try:
            while not self._stopping:
                for fd, events in poll.poll(self._wait_ms()):
                    client = clients.get(fd)
                    if client is not None:
                        requests.serve(client, events, answer)
                    elif fd in handshakes:
                        handshakes.step(fd)
                    elif fd in listeners:
                        self._accept(*listeners[fd])
                    elif fd == self._wake_fd:
                        listeners = self._woken()
                if handshakes:
                    handshakes.expire(self.request_timeout_s)
                if clients or self._resting:
                    self._sweep()
        except Exception:
            log.exception("table server: internal error; TCP clients no longer reach the table")
        finally:
            self._close_all()

    # --- connections ---

    def _accept(self, listener: socket.socket, tls: bool) -> None:
        accepted = self._rest.accept(listener, lambda rest_s: self._rest_listener(listener,
                                                                                  rest_s))
        if accepted is None:
            return
        sock, address = accepted
        if self._allows is not None and not self._allows(address[0]):
            sock.close()
            self.refused_authip += 1
            self._warn.warn(address[0], "authip", "table client %s refused: not in authip",
                            format_address(address), kind=Kind.CONNECTION_REFUSED,
                            client=format_address(address), reason="not in authip")
            return
        if not self._room_for(sock, address):
            return
        sock.setblocking(False)
        if tls:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)   # no Nagle in the flights
            self._handshakes.start(self._tls, sock, address, self.request_timeout_s)
        else:
            self._adopt(Connection(sock, format_address(address), address[0]))

    def _rest_listener(self, listener: socket.socket, rest_s: float) -> None:
        self._poll.unregister(listener.fileno())
        self._resting[listener.fileno()] = time.monotonic() + rest_s

    def _room_for(self, sock: socket.socket, address) -> bool:
        """Whether a newcomer fits (a silent or slow client closed for it if need be); else
        sock is closed."""
        host = address[0]
        mine = [c for c in self._clients.values() if c.host == host]
        limit = self.max_connections
        per_address = min(limit, max(PER_ADDRESS, share(limit)))   # a small cap: one host's
        if len(mine) >= per_address:
            pool, why = mine, f"{per_address} table clients of this address are connected"
        elif len(self._clients) >= limit:
            pool, why = list(self._clients.values()), \
                f"{limit} table clients are connected, the most there may be " \
                f"(table.max-connections)"
        else:
            return True
        victim = eviction_victim(pool, time.monotonic())
        if victim is not None:
            self.evicted += 1
            log.debug("table client %s closed to make room for %s", victim.peer,
                      format_address(address))
            self._close(victim)
            return True
        sock.close()
        self.refused_limit += 1
        self._warn.warn(host, "limit", "table client %s refused: %s", format_address(address), why,
                        kind=Kind.CONNECTION_REFUSED, client=format_address(address),
                        reason="too many table clients")
        return False

    def _sweep(self) -> None:
        """Close the clients whose request is late (request_timeout_s after its first byte)
        or that sent none for FIRST_REQUEST_S; listeners that have rested listen again."""
        now = time.monotonic()
        if now - self._swept < SWEEP_S:
            return
        self._swept = now
        for fd, until in list(self._resting.items()):
            if now >= until:
                del self._resting[fd]
                self._poll.register(fd, _IN)
        for client in list(self._clients.values()):
            reason = late(client, now, self.request_timeout_s)
            if reason is None:
                continue
            self.timed_out += 1
            self._warn.warn(client.host, "timeout", "table client %s closed: %s", client.peer,
                            reason)
            self._close(client)

    def _adopt(self, client: Connection) -> None:
        client.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        client.guard = self.firewall.guard(client.host, client.role, client.listener)
        self._clients[client.fd] = client
        self._poll.register(client.fd, _IN)
        self.accepted += 1
        self._last_id += 1
        client.id = self._last_id
        log.debug("table client %s connected%s", client.peer,
                  f" (TLS, role {client.role})" if client.tls else "")

    # --- Modbus/TCP Security: the ends of a handshake (mbgw.table.handshakes steps it) ---

    def _tls_client(self, sock: ssl.SSLSocket, address) -> None:
        """A client whose handshake is over: served like a plain one, its role (from its
        certificate) for the firewall."""
        try:
            role = role_of(sock.getpeercert(binary_form=True))
        except (OSError, ValueError):       # the peer has gone meanwhile
            sock.close()
            return
        if not self._room_for(sock, address):
            return
        client = Connection(sock, format_address(address), address[0], role, tls=True)
        self._adopt(client)
        if sock.pending():                  # a request came with the handshake's end
            self._requests.receive(client, self._answer)

    def _tls_probe(self) -> None:
        self.tls_probes += 1

    def _tls_refused(self, address, reason: str) -> None:
        """Counted; logged at most once a minute per address and reason."""
        self.refused_tls += 1
        if self._tls_refusals.due((address[0], reason)) is not None:
            event(log, Kind.TLS_REFUSED, "table client %s refused: %s (further TLS refusals of "
                  "this address for this reason are logged at most once a minute)",
                  format_address(address), reason, client=format_address(address), reason=reason)

    # --- waiting, closing ---

    def _wait_ms(self) -> int | None:
        """poll()'s timeout: until the first handshake's deadline, and at most SWEEP_S while
        clients have deadlines or a listener rests (None: nothing to wait for)."""
        wait = int(SWEEP_S * 1000) + 1 if self._clients or self._resting else None
        first_ms = self._handshakes.wait_ms()
        if first_ms is None or wait is None:
            return wait if first_ms is None else first_ms
        return min(wait, first_ms)

    def _close(self, client: Connection) -> None:
        del self._clients[client.fd]
        self._poll.unregister(client.fd)
        client.sock.close()
        log.debug("table client %s disconnected", client.peer)

    def _close_all(self) -> None:
        for client in list(self._clients.values()):
            self._close(client)
        self._handshakes.close()
        for sock in self._ports.sockets():
            sock.close()
        self._resting.clear()
        os.close(self._wake_fd)

    def _woken(self) -> dict:
        drain(self._wake_fd)
        with self._lock:
            new, self._new_listeners = self._new_listeners, None
            firewall, self._new_firewall = self._new_firewall, None
            new_tls, self._new_tls = self._new_tls, None
            new_allows, self._new_allows = self._new_allows, None
            new_bind, self._new_bind = self._new_bind, None
            to_close, self._to_close = self._to_close, []
        for client_id, who in to_close:
            self._close_by_operator(client_id, who)
        if new_allows is not None:
            self._reaccess(new_allows[0])
        if new_bind is not None:
            self._rebind(*new_bind)
        if firewall is not None:
            self._requests.firewall = firewall
            for client in self._clients.values():
                client.guard = firewall.guard(client.host, client.role, client.listener)
        if new_tls is not None:
            self._tls, tls_listeners = new_tls
            if tls_listeners is not None:
                old, self._ports.tls = self._ports.tls, tls_listeners
                self._relisten(old, tls_listeners)
            else:
                log.info("table server: TLS certificate loaded for new connections")
        if new is not None:
            old, self._ports.plain = self._ports.plain, new
            self._relisten(old, new)
        return self._ports.by_fd()

    def _close_by_operator(self, client_id: int, who: str) -> None:
        for client in list(self._clients.values()):
            if client.id == client_id:
                event(log, Kind.CLIENT_CLOSED, "table client %s closed by the operator (%s)",
                      client.peer, who, client=client.peer, user=who)
                self._close(client)

    def _reaccess(self, allows) -> None:
        self._allows = allows
        if allows is None:
            return
        for client in list(self._clients.values()):
            if not allows(client.host):
                event(log, Kind.CLIENT_CLOSED, "table client %s closed: no longer allowed by "
                      "authip", client.peer, client=client.peer, reason="not in authip")
                self._close(client)
        self._handshakes.close(allows)

    def _rebind(self, bind: str | None, outcome: queue.Queue) -> None:
        """Off the old address, on the new one; back on the old one when the new one cannot
        be listened on."""
        self._relisten(self._ports.sockets(), [], quiet=True)
        error, again = self._ports.rebind(bind)
        if again is not None:
            log.error("table server: %s; no TCP client reaches the table", again.strerror)
        self._relisten([], self._ports.sockets())
        outcome.put(error)      # once the listeners are whatever they stay: rebind() reports them

    def _relisten(self, old: list[socket.socket], new: list[socket.socket],
                  quiet: bool = False) -> None:
        for sock in old:
            if self._resting.pop(sock.fileno(), None) is None:
                self._poll.unregister(sock.fileno())
            sock.close()
        for sock in new:
            self._poll.register(sock.fileno(), _IN)
        if not quiet:
            log.info("table server: listening on %s", ", ".join(self.addresses) or "no port")
