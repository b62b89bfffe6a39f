"""Slave mode's network side: the Modbus TCP server on mdbport.

The asyncio thread listens and admits.  authip is checked as soon as a connection is
accepted, before any byte is read.  The limits count live connections: one whose peer has
closed or reset it is forgotten first, even before the line thread has read its end.  A
newcomer over max_connections_per_ip is refused; over max_connections it takes the place of
an idle client (eviction_victim), or is refused when none may go.  A request begun and not
whole within request-timeout, or no request within FIRST_REQUEST_S, closes its connection
(_sweep).  An accept() that fails for want of descriptors rests the listener (AcceptRest):
it never spins.  An admitted connection
then belongs to the line thread
(mbgw.slave.connections), which calls request() for each frame it reads and finished() with each
outcome: one thread carries a transaction from the client's bytes to the reply.

With the exchange table on, a request for it (routes_to_table) is answered at once by the
thread that read it: the line thread, or while that thread is in a serial transaction the
table reader (mbgw.slave.table_reader), which calls read_meanwhile() and keeps the requests
for the line for the line thread (take_kept).  Both hold the line worker's gate meanwhile.

Each unit's hop (mbgw.slave.routes) says where its request goes: today's way to line serial,
the table, line serial with the unit rewritten, nowhere (0x0A or silence), or another target
(a line, a remote server) as an Exchange in its Inbox.  That target's thread hands the
outcome back through a deque and the wake-up eventfd, and whoever holds the gate delivers it
(_deliver_completions): a client is only ever touched under the gate.
"""
import asyncio
import dataclasses
import logging
import select
import socket
import ssl
import time
from collections import deque

from mbgw.audit import Kind, event, operator
from mbgw.config.lines import PRIMARY_LINE
from mbgw.config.model import ACTIVE_WINDOW_S, SlaveConfig
from mbgw.errors import ConfigError
from mbgw.firewall.guard import Firewall
from mbgw.line import clients
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceTable
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.limits import AcceptRest, WarnLimit, is_resource_error
from mbgw.ops.reload import ReloadReport
from mbgw.ops.service import ListenError
from mbgw.ops.tls import role_of, server_context
from mbgw.ops.trace import Outcome, TraceEvent, TraceHub
from mbgw.protocol import mbap, pdu
from mbgw.routing.exchange import Exchange
from mbgw.routing.inbox import Inbox
from mbgw.slave.acl import AccessList
from mbgw.slave.client import PEER_GONE, Client, TlsClient
from mbgw.slave.connections import Connections
from mbgw.slave.handshakes import HANDSHAKES_PER_ADDRESS, MAX_HANDSHAKES, Handshakes
from mbgw.slave.routes import (
    DIRECT,
    SERIAL,
    TABLE,
    Hop,
    answered_off_the_line,
    effective_routes,
    face_hops,
    is_today,
)
from mbgw.slave.scheduler import Job, Scheduler

log = logging.getLogger("mbgw.tcp")

LISTEN_BACKLOG = 100
FIRST_REQUEST_S = 60.0           # a connection that sent no whole request this long is closed
SLOW_REQUEST_S = 0.5             # a request begun this long ago and not whole: a slow client
SWEEP_S = 0.25                   # how often the clients' deadlines are looked at


class TcpServer:
    def __init__(self, cfg: SlaveConfig, scheduler: Scheduler, counters: Counters,
                 line_up, devices: DeviceTable, table=None,
                 inboxes: dict[str, Inbox] | None = None) -> None:
        """table: the exchange table (mbgw.table.memory.Table), served while cfg.table is
        enabled.  inboxes: the other targets' (lines by name, servers by target label), a
        dict the daemon keeps up to date before each reconfigure()."""
        self._cfg = cfg
        self._scheduler = scheduler
        self.counters = counters
        self._line_up = line_up          # callable: is the serial line usable?
        self._devices = devices
        self._down = devices.rule.down   # the addresses that are down, by address
        self._acl = AccessList(cfg.authip)
        self.firewall = Firewall(cfg.firewall, cfg.tls.roles_required)
        self.clients: list[Client] = []  # the asyncio thread's list, for admission and status
        self._warn = WarnLimit(log)
        self._evictions = WarnLimit(log, level=logging.INFO)
        self._accept_rest = AcceptRest(log, "Modbus TCP")
        self._sweeper: asyncio.TimerHandle | None = None
        self._listeners: list[socket.socket] = []
        self._tls_listeners: list[socket.socket] = []
        self._tls = server_context(cfg.tls) if cfg.tls.enabled else None   # ConfigError
        self._handshakes: Handshakes | None = None     # once the loop runs
        self._loop: asyncio.AbstractEventLoop | None = None
        self.trace = TraceHub()
        self.connections = Connections(scheduler.wake_fd, self.request, self._closed, counters)
        self.table = table
        # Each unit's hop (mbgw.slave.routes); swapped whole at a reload, so the threads that
        # route never see half of it.
        self.inboxes: dict[str, Inbox] = inboxes if inboxes is not None else {}
        self._face: list[Hop | None] = []
        self.route_face(cfg)
        self._responder = table.responder() if table is not None else None   # line thread's
        self._kept: list[tuple] = []     # requests for the line read by the table reader
        # Exchanges other lines answered, for the thread that holds the gate to deliver
        self._completions: deque[tuple] = deque()
        self.connections.on_wake = self._deliver_completions

    def route_face(self, cfg: SlaveConfig) -> None:
        """The face's hops for cfg, swapped whole.  At a reload the line thread calls it
        between two turns (LineWorker._configure), so that the C shortcut never takes a
        request the new routes send elsewhere."""
        face = face_hops(effective_routes(cfg), self.inboxes, self.table is not None)
        self.shortcut_allowed = is_today(face) and not cfg.table_on
        self.reads_meanwhile = answered_off_the_line(face)
        self._face = face

    # --- the asyncio thread: listening and admission ---

    async def start(self) -> list[str]:
        """Listen; returns the listening addresses.  Raises OSError."""
        self._loop = asyncio.get_running_loop()
        self._handshakes = Handshakes(self._loop, self._admit_tls, self._tls_refused,
                                      self._tls_probe)
        self._handshakes.timeout_s = self._cfg.request_timeout_ms / 1000
        self._listen_plain()
        try:
            self._listen_tls()
        except OSError as err:
            self._stop_listening()
            raise ListenError(self._cfg.tls.port, err) from None
        self._sweeper = self._loop.call_later(SWEEP_S, self._sweep)
        return self.addresses()

    def _listen_plain(self) -> None:
        """Listen on mdbport (0: not at all).  Raises OSError."""
        assert self._loop is not None
        if self._cfg.mdbport:
            self._listeners = listen(self._cfg.bind, self._cfg.mdbport)
        for sock in self._listeners:
            self._loop.add_reader(sock.fileno(), self._accept, sock)

    def _listen_tls(self) -> None:
        """Listen on tls-port while TLS is on.  Raises OSError."""
        assert self._loop is not None
        if self._tls is not None:
            self._tls_listeners = listen(self._cfg.bind, self._cfg.tls.port)
        for sock in self._tls_listeners:
            self._loop.add_reader(sock.fileno(), self._accept_tls, sock)

    def addresses(self) -> list[str]:
        return [format_address(s.getsockname()) for s in self._listeners] + \
            [f"{format_address(s.getsockname())} (TLS)" for s in self._tls_listeners]

    def _stop_listening(self, tls: bool = False) -> None:
        """Stop listening on mdbport, or (tls) on tls-port."""
        listeners = self._tls_listeners if tls else self._listeners
        for sock in listeners:
            if self._loop is not None:
                self._loop.remove_reader(sock.fileno())
            sock.close()
        listeners.clear()

    async def reconfigure(self, cfg: SlaveConfig, report: ReloadReport) -> None:
        """Apply new settings; connections they do not concern stay open.  What cannot be
        applied (a port another program holds, TLS files that do not load) stays as it was,
        told to the report."""
        old, self._cfg = self._cfg, cfg
        self._acl = AccessList(cfg.authip)
        if self._handshakes is not None:
            self._handshakes.timeout_s = cfg.request_timeout_ms / 1000
        self._guard_clients(self.firewall.renewed(cfg.firewall, cfg.tls.roles_required))
        if self.table is not None and cfg.table.functions != old.table.functions:
            self.table.set_functions(cfg.table.functions)
        for client in list(self.clients):
            if not self._acl.allows(client.host):
                event(log, Kind.CLIENT_CLOSED, "client %s closed: no longer allowed by authip",
                      client.peer, client=client.peer, reason="not in authip")
                self._drop(client)
        if cfg.tls != old.tls or cfg.bind != old.bind:
            self._retls(old, report)
        if (cfg.mdbport, cfg.bind) != (old.mdbport, old.bind):
            self._stop_listening()
            try:
                self._listen_plain()
            except OSError as err:
                where = f"{cfg.bind or '*'} port {cfg.mdbport}"
                for setting in ("mdbport", "bind"):
                    if getattr(cfg, setting) != getattr(old, setting):
                        report.refuse(setting, f"cannot listen on {where} ({err.strerror}): "
                                               f"still on port {old.mdbport}")
                self._cfg = dataclasses.replace(self._cfg, mdbport=old.mdbport, bind=old.bind)
                self._listen_plain()
            log.info("now listening on %s", ", ".join(self.addresses()))

    def _retls(self, old: SlaveConfig, report: ReloadReport) -> None:
        """New TLS settings or renewed files: the new context is for new connections; those
        open keep theirs.  One that cannot be loaded, or a port that cannot be listened on,
        leaves TLS as it was."""
        new = self._cfg.tls
        try:
            context = server_context(new) if new.enabled else None
        except ConfigError as err:
            report.refuse("tls", f"{err}; the running TLS settings stay")
            self._cfg = dataclasses.replace(self._cfg, tls=old.tls)
            return
        if (new.port, new.enabled, self._cfg.bind) == (old.tls.port, old.tls.enabled, old.bind):
            self._tls = context
            log.info("TLS: certificate %s loaded for new connections", new.cert)
            return
        self._stop_listening(tls=True)
        running, self._tls = self._tls, context
        try:
            self._listen_tls()
        except OSError as err:
            report.refuse("tls", f"cannot listen on tls-port {new.port} ({err.strerror}); "
                                 f"the running TLS settings stay")
            self._cfg = dataclasses.replace(self._cfg, tls=old.tls)
            self._tls = running
            self._listen_tls_again(old)
            return
        log.info("now listening on %s", ", ".join(self.addresses()))

    def _listen_tls_again(self, old: SlaveConfig) -> None:
        """Back on the running tls-port, after the new one failed."""
        try:
            self._listen_tls()
        except OSError as err:
            log.error("TLS: cannot listen on tls-port %d again (%s): no TLS listener",
                      old.tls.port, err.strerror)

    def _guard_clients(self, firewall: Firewall) -> None:
        """The rules again for every client (a reload): a client whose rule has not changed
        keeps what it may do; none is closed."""
        if firewall is self.firewall:
            return
        self.firewall = firewall
        for client in self.clients:
            client.guard = firewall.guard(client.host, client.role, client.listener)

    def close(self) -> None:
        if self._sweeper is not None:
            self._sweeper.cancel()
        self._stop_listening()
        self._stop_listening(tls=True)
        if self._handshakes is not None:
            self._handshakes.close()
        for client in list(self.clients):
            self._drop(client)

    def _accept(self, listener: socket.socket) -> None:
        sock, address = self._accepted(listener, self._accept)
        if sock is None:
            return
        sock.setblocking(False)
        client = Client(sock, address[0], format_address(address),
                        format_address(sock.getsockname()))
        self._welcome(client)

    def _accepted(self, listener: socket.socket, handler) -> tuple:
        """(socket, address) of a newcomer on listener, or (None, None): none waits, or the
        process is out of descriptors or memory, and then the listener rests (it would be
        readable at once again: the loop would spin)."""
        try:
            accepted = listener.accept()
        except (BlockingIOError, InterruptedError, ConnectionAbortedError):
            return None, None
        except OSError as err:
            if is_resource_error(err):
                self._rest(listener, handler, err)
            else:
                log.debug("cannot accept a connection: %s", err.strerror or err)
            return None, None
        self._accept_rest.accepted()
        return accepted

    def _rest(self, listener: socket.socket, handler, err: OSError) -> None:
        loop = self._loop
        assert loop is not None
        loop.remove_reader(listener.fileno())
        loop.call_later(self._accept_rest.failed(err), self._resume, listener, handler)

    def _resume(self, listener: socket.socket, handler) -> None:
        if self._loop is not None and (listener in self._listeners
                                       or listener in self._tls_listeners):
            self._loop.add_reader(listener.fileno(), handler, listener)

    def _sweep(self) -> None:
        """Close the connections whose request has been begun for longer than request-timeout,
        and those that have sent no whole request for FIRST_REQUEST_S."""
        assert self._loop is not None
        self._sweeper = self._loop.call_later(SWEEP_S, self._sweep)
        now = time.monotonic()
        limit_s = self._cfg.request_timeout_ms / 1000
        for client in list(self.clients):
            since = client.partial_since
            if since and now - since > limit_s:
                reason = f"a request not whole within request-timeout " \
                         f"({self._cfg.request_timeout_ms} ms)"
            elif not client.requests and now - client.opened > FIRST_REQUEST_S:
                reason = f"no request within {FIRST_REQUEST_S:g} s"
            else:
                continue
            self.counters.connections_timed_out += 1
            self._warn.warn(client.host, "timeout", "client %s closed: %s", client.peer,
                            reason)
            self._drop(client)

    def _welcome(self, client: Client) -> None:
        """An accepted client admitted (within the limits) and handed to the line thread, or
        closed."""
        if not self.admit(client, client.host):
            client.sock.close()
            return
        client.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        self.connections.adopt(client)

    # --- Modbus/TCP Security: accepted here, the handshake in mbgw.slave.handshakes ---

    def _accept_tls(self, listener: socket.socket) -> None:
        sock, address = self._accepted(listener, self._accept_tls)
        if sock is None:
            return
        host = address[0]
        if not self._acl.allows(host):          # before any byte is read
            self.counters.connections_refused_authip += 1
            self._log_refusal(host, "not in authip")
            sock.close()
            return
        handshakes = self._handshakes
        assert handshakes is not None
        per_ip = min(HANDSHAKES_PER_ADDRESS, self._cfg.max_connections_per_ip or MAX_HANDSHAKES)
        if handshakes.full or self._tls is None or handshakes.from_host(host) >= per_ip:
            self.counters.connections_refused_tls += 1
            self._log_refusal(host, f"{MAX_HANDSHAKES} TLS handshakes under way already"
                              if handshakes.full else
                              f"{per_ip} TLS handshakes of this address under way already",
                              Kind.TLS_REFUSED)
            sock.close()
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)   # no Nagle in the flights
        handshakes.start(self._tls, sock, address)

    def _tls_refused(self, host: str, reason: str) -> None:
        self.counters.connections_refused_tls += 1
        self._log_refusal(host, reason, Kind.TLS_REFUSED)

    def _tls_probe(self, host: str) -> None:
        """A connection to the TLS port closed or reset before its first byte (a health
        check): counted, not a refused handshake."""
        self.counters.connections_tls_probes += 1
        log.debug("connection from %s to the TLS port closed before the handshake", host)

    def _admit_tls(self, sock: ssl.SSLSocket, address) -> None:
        try:
            role = role_of(sock.getpeercert(binary_form=True))
            client = TlsClient(sock, address[0], format_address(address),
                               format_address(sock.getsockname()), role)
        except OSError:                 # the peer has gone meanwhile
            sock.close()
            return
        log.debug("client %s: TLS %s, role %s", client.peer, sock.version(), role)
        self._welcome(client)

    def admit(self, client: Client, host: str) -> bool:
        if not self._acl.allows(host):
            self.counters.connections_refused_authip += 1
            self._log_refusal(host, "not in authip")
            return False
        if not self._room_for(client):
            self.counters.connections_refused_limit += 1
            return False
        self.counters.connections_accepted += 1
        client.guard = self.firewall.guard(host, client.role, client.listener)
        self.clients.append(client)
        log.debug("client %s connected", client.peer)
        return True

    def _room_for(self, newcomer: Client) -> bool:
        """Whether newcomer fits within the limits, an idle client closed for it if need be."""
        per_ip = self._cfg.max_connections_per_ip
        if per_ip and len(self._live(c for c in self.clients if c.host == newcomer.host)) \
                >= per_ip:
            self._log_refusal(newcomer.host, f"it has max-connections-per-ip ({per_ip}) open")
            return False
        if len(self.clients) < self._cfg.max_connections:
            return True
        live = self._live(self.clients)
        if len(live) < self._cfg.max_connections:
            return True
        now = time.monotonic()
        idle = [c for c, events in live.items()
                if not (c.in_flight or c.output_waiting)
                and (not events & select.POLLIN or slow(c, now))]
        victim = eviction_victim(idle, now)
        if victim is None:
            self._warn.warn(newcomer.host, "busy", "client %s refused: all %d connections of "
                            "net.max-connections are busy (a request in the gateway, or one "
                            "within the last %d s)", newcomer.peer, len(live), ACTIVE_WINDOW_S,
                            kind=Kind.CONNECTION_REFUSED, client=newcomer.peer,
                            reason="max-connections, every client busy")
            return False
        self._evictions.warn(victim.host, "evicted", "client %s closed to make room for %s",
                             victim.peer, newcomer.peer)
        self.counters.connections_evicted += 1
        self._drop(victim)
        return True

    def _live(self, clients) -> dict[Client, int]:
        """Those of clients whose peer is still there, with what poll() says of each; the
        others, which the line thread has not seen end yet, are forgotten now."""
        live = {}
        for client in list(clients):
            events = client.probe()
            if events & PEER_GONE:
                self.forget(client)
            else:
                live[client] = events
        return live

    def close_client(self, client_id: int, user=None) -> bool:
        """Force-close a client connection (operator's command; user: who, as the control
        command's "uid" names them)."""
        for client in self.clients:
            if client.id == client_id:
                event(log, Kind.CLIENT_CLOSED, "client %s closed by the operator (%s)",
                      client.peer, operator(user), client=client.peer, user=operator(user))
                self._drop(client)
                return True
        return False

    def _drop(self, client: Client) -> None:
        """End a connection now; the line thread closes it when it sees it end."""
        client.shutdown()
        self.forget(client)

    def forget(self, client: Client) -> None:
        if client in self.clients:
            self.clients.remove(client)
            log.debug("client %s disconnected", client.peer)

    def _log_refusal(self, host: str, reason: str,
                     kind: Kind = Kind.CONNECTION_REFUSED) -> None:
        """Logged at most once a minute per address and reason (with how many were left out):
        a refusal of one kind never hides another kind from the same address."""
        self._warn.warn(host, reason, "connection from %s refused: %s", host, reason,
                        kind=kind, client=host, reason=reason)

    # --- the line thread: requests in, outcomes out ---

    def request(self, client: Client, tid: int, unit: int, request: bytes,
                received_ns: int = 0) -> None:
        """A request read from client, which arrived at received_ns (0: client.arrived_ns)."""
        client.requests += 1
        guard = client.guard
        if guard is not None and not guard.allows(unit, request):
            self._refused_by_firewall(client, guard, tid, unit, request, received_ns)
            return
        hop = self._face[unit]
        if hop is DIRECT:
            job = self._admit(client, tid, unit, request, received_ns or client.arrived_ns)
            if job is not None:
                client.in_flight += 1
                self._scheduler.submit(client.queue, job)
            return
        self._elsewhere(hop, client, tid, unit, request, received_ns or client.arrived_ns,
                        self._responder)

    def _elsewhere(self, hop: Hop | None, client: Client, tid: int, unit: int,
                   request: bytes, received_ns: int, responder) -> None:
        """A request the face's routes take elsewhere than today's way to line serial."""
        if hop is None:
            self.counters.requests += 1
            if self.trace.active:
                self.trace.emit_threadsafe(self._event("request", client, tid, unit, request,
                                                       "", None, None))
            self.counters.unroutable += 1
            self._refuse(client, tid, unit, request, Outcome.UNROUTABLE, received_ns,
                         line=None)
            return
        kind = hop.kind
        if kind is TABLE:
            self._from_table(client, tid, unit, request, responder,
                             hop.rewrite(unit) == pdu.BROADCAST)
        elif kind is SERIAL:
            job = self._admit(client, tid, unit, request, received_ns, hop.rewrite(unit))
            if job is not None:
                client.in_flight += 1
                self._scheduler.submit(client.queue, job)
        else:
            self.counters.requests += 1
            if self.trace.active:
                self.trace.emit_threadsafe(self._event("request", client, tid, unit, request,
                                                       "", None, hop.line))
            inbox = hop.inbox
            assert inbox is not None
            client.in_flight += 1
            inbox.submit(Exchange(client, hop.rewrite(unit), request, received_ns,
                                  self._completed, (client, tid, unit, hop.line)))

    def _completed(self, exchange: Exchange, reply: bytes | None, outcome: str) -> None:
        """The target's thread: the outcome waits for the thread that holds the gate (the
        client is touched by no other)."""
        self._completions.append((exchange, reply, outcome))
        self._scheduler.wake()

    def _deliver_completions(self) -> None:
        """Under the gate (the line thread, or the table reader): the other lines' outcomes
        to their clients, under the client's own transaction id and unit."""
        completions = self._completions
        while completions:
            exchange, reply, outcome = completions.popleft()
            client, tid, unit, line = exchange.context
            client.in_flight -= 1
            self._answer(client, tid, unit, reply)
            if self.trace.active:
                self.traced(client, tid, unit, exchange.pdu[0], reply, outcome,
                            exchange.received_ns, line)

    # --- the table reader, under the gate while the line thread is in a serial transaction

    def read_meanwhile(self, client: Client, tid: int, unit: int, request: bytes,
                       responder) -> None:
        """A request the table reader read: a table request is answered now (with the
        reader's own responder); one for the line is kept for the line thread, in flight
        already so that the client's limit of requests in the gateway holds."""
        hop = self._face[unit]
        if hop is not None and hop.kind is SERIAL:
            client.in_flight += 1
            self._kept.append((client, tid, unit, request, client.arrived_ns))
            return
        client.requests += 1
        guard = client.guard
        if guard is not None and not guard.allows(unit, request):
            self._refused_by_firewall(client, guard, tid, unit, request, client.arrived_ns)
        else:
            self._elsewhere(hop, client, tid, unit, request, client.arrived_ns, responder)

    def take_kept(self) -> None:
        """Line thread, under the gate: route the requests the table reader kept for the line,
        in the order they were read."""
        kept = self._kept
        if not kept:
            return
        for client, tid, unit, request, received_ns in kept:
            client.in_flight -= 1
            if not client.closed:
                self.request(client, tid, unit, request, received_ns)
        kept.clear()

    def _from_table(self, client: Client, tid: int, unit: int, request: bytes,
                    responder, broadcast: bool) -> None:
        """Answer a request from the exchange table at once; unit 0 is a broadcast into it
        (direct messaging off), with no reply."""
        self.counters.requests += 1
        tracing = self.trace.active
        if tracing:
            self.trace.emit_threadsafe(self._event("request", client, tid, unit, request, "",
                                                   None, None))
        if broadcast:
            reply = responder.answer(request, broadcast=True)
        else:
            reply = responder.answer(request)
        self._answer(client, tid, unit, reply)
        if tracing:
            self.traced(client, tid, unit, request[0], reply, Outcome.TABLE, client.arrived_ns,
                        None)

    def _refused_by_firewall(self, client: Client, guard, tid: int, unit: int,
                             request: bytes, received_ns: int) -> None:
        """A request the client's rule does not allow: 0x01 (a broadcast's too: it was not
        done); it reaches neither the line nor the table."""
        self.counters.requests += 1
        client.firewall_refused += 1
        tracing = self.trace.active
        if tracing:
            self.trace.emit_threadsafe(self._event("request", client, tid, unit, request, "",
                                                   None, None))
        reply = self.firewall.refused(guard, client.peer, client.role, unit, request)
        self._answer(client, tid, unit, reply)
        if tracing:
            self.traced(client, tid, unit, request[0], reply, Outcome.FIREWALL,
                        received_ns or client.arrived_ns, None)

    def taken(self, client: Client, tid: int, unit: int, request: bytes,
              received_ns: int) -> Job | None:
        """A request the line worker put on the idle line itself (its shortcut, which takes
        only what routes, never for an address that is down) after it arrived at
        received_ns, counted, checked and traced as request() does; the client has it in
        flight and counted already."""
        return self._admit(client, tid, unit, request, received_ns)

    def _admit(self, client: Client, tid: int, unit: int, request: bytes,
               received_ns: int, address: int = 0) -> Job | None:
        """The job for a request that arrived at received_ns, or None when it was answered
        at once (it cannot reach the line, or its address is down and this is no probe: it
        must not wait in the queue for a refusal)."""
        self.counters.requests += 1
        tracing = self.trace.active
        if tracing:
            self.trace.emit_threadsafe(self._event("request", client, tid, unit, request, "",
                                                   None))
        address = address or self._cfg.slaveid or unit
        if address > pdu.MAX_SERIAL_ADDRESS:
            self.counters.unroutable += 1
            self._refuse(client, tid, unit, request, Outcome.UNROUTABLE, received_ns)
            return None
        if not self._line_up():
            self.counters.line_down_rejects += 1
            self._refuse(client, tid, unit, request, Outcome.LINE_DOWN, received_ns)
            return None
        down = self._down[address] == 1
        if down:
            device = self._devices.get(address)
            if not device.admit(time.monotonic()):
                self.counters.demoted_rejects += 1
                self._refuse(client, tid, unit, request, Outcome.DEVICE_DOWN, received_ns,
                             pdu.GATEWAY_TARGET_FAILED, device)
                return None
        return Job(client, tid, unit, bytes((address,)) + request, received_ns, probe=down)

    def finished(self, job: Job, reply: bytes | None, sent: int = -1) -> None:
        """job's outcome: its reply (if any) goes out at once, or its rest when the serial
        receive sent `sent` bytes of it already."""
        client = job.client
        if sent < 0:            # else C counted it answered as it sent the reply
            client.in_flight -= 1
        self._answer(client, job.tid, job.unit, reply, sent)
        if self.trace.active:
            self.traced(client, job.tid, job.unit, job.adu[1], reply, job.outcome,
                        job.received_ns)

    def _closed(self, client: Client) -> None:
        self._scheduler.discard(client.queue)
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.forget, client)

    def _answer(self, client: Client, tid: int, unit: int, reply: bytes | None,
                sent: int = -1) -> None:
        if reply is not None and not client.closed:
            if sent < 0:
                client.send(mbap.frame(tid, unit, reply))
            elif sent < mbap.HEADER_LEN + len(reply):
                client.send(mbap.frame(tid, unit, reply)[sent:])
            self.counters.replies += 1
            client.last_active = time.monotonic()

    def _refuse(self, client: Client, tid: int, unit: int, request: bytes, outcome: str,
                received_ns: int, code: int = pdu.GATEWAY_PATH_UNAVAILABLE,
                device=None, line: str | None = PRIMARY_LINE) -> None:
        reply = gateway_exception(self._cfg.exception, request[0], code, self.counters,
                                  device)
        self._answer(client, tid, unit, reply)
        if self.trace.active:
            self.traced(client, tid, unit, request[0], reply, outcome, received_ns, line)

    def traced_late(self, job: Job, reply: bytes) -> None:
        """The late reply to job, which timed out, was dropped (while someone traces)."""
        if self.trace.active:
            self.trace.emit_threadsafe(self._event("late", job.client, job.tid, job.unit,
                                                   reply, Outcome.LATE, None))

    def traced(self, client: Client, tid: int, unit: int, function: int, reply: bytes | None,
               outcome: str, received_ns: int, line: str | None = PRIMARY_LINE) -> None:
        latency_ms = (time.monotonic_ns() - received_ns) / 1e6 if received_ns else None
        if reply is None:
            event = self._event("no reply", client, tid, unit, bytes((function,)), outcome,
                                latency_ms, line)
        else:
            event = self._event("reply", client, tid, unit, reply, outcome, latency_ms, line)
        self.trace.emit_threadsafe(event)

    @staticmethod
    def _event(direction: str, client: Client, tid: int, unit: int, data: bytes,
               outcome: str, latency_ms, line: str | None = PRIMARY_LINE) -> TraceEvent:
        return {"time": time.time(), "line": line, "direction": direction, "client": client.id,
                "peer": client.peer, "local": client.local, "remote": client.peer,
                "tid": tid, "unit": unit,
                "function": data[0], "length": len(data) if direction != "no reply" else 0,
                "pdu": data.hex() if direction != "no reply" else "", "outcome": outcome,
                "latency_ms": latency_ms}


def slow(client: Client, now: float) -> bool:
    """A request begun SLOW_REQUEST_S ago or more and still not whole."""
    return bool(client.partial_since) and now - client.partial_since >= SLOW_REQUEST_S


def eviction_victim(idle: list[Client], now: float) -> Client | None:
    """The client with nothing in the gateway that a newcomer takes the place of: of those
    that never sent a whole request (silent, or dribbling one), the least recently active;
    else of those slow with a request, the least recently active; else the least recently
    active of those quiet for ACTIVE_WINDOW_S; None when every one is polling."""
    silent = [c for c in idle if not c.requests]
    quiet = silent or [c for c in idle if slow(c, now)] or \
        [c for c in idle if not c.busy and now - c.last_active >= ACTIVE_WINDOW_S]
    return min(quiet, key=lambda c: c.last_active, default=None)


def listen(bind: str | None, port: int) -> list[socket.socket]:
    """Listening sockets on bind (None: every interface, IPv4 and IPv6) and port."""
    infos = socket.getaddrinfo(bind, port, socket.AF_UNSPEC, socket.SOCK_STREAM, 0,
                               socket.AI_PASSIVE)
    sockets = []
    try:
        for family, kind, proto, _, address in dict.fromkeys(infos):
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            clients.stamp_arrivals(sock.fileno())    # its connections' requests are dated
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
            sock.listen(LISTEN_BACKLOG)
            sock.setblocking(False)
    except OSError:
        for sock in sockets:
            sock.close()
        raise
    return sockets


def format_address(name) -> str:
    host, port = name[:2]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
