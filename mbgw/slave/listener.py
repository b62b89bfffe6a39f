"""Slave mode's Modbus TCP listeners, on the asyncio thread: mdbport, tls-port and rtu-port
(RTU over TCP), accept and admission, eviction, the request deadlines, the reload of the
listeners, and the operator's close; and the sockets of udp-port, handed to the line thread
(mbgw.slave.udp_face), which reads them.

authip is checked as soon as a connection is accepted, before any byte is read.  The limits
count live connections: one whose peer has closed or reset it is forgotten first, even before
the line thread has read its end.  A newcomer over max_connections_per_ip is refused; over
max_connections it takes the place of an idle client (eviction_victim), or is refused when
none may go.  A request begun and not whole within request-timeout, or no request within
FIRST_REQUEST_S, closes its connection (_sweep).  An accept() that fails for want of
descriptors rests the listener (AcceptRest): it never spins.  An admitted connection then
belongs to the line thread (mbgw.slave.connections, and mbgw.slave.router for its requests).
"""
import asyncio
import dataclasses
import logging
import select
import socket
import ssl
import time

from mbgw.audit import Kind, event, operator
from mbgw.config.model import ACTIVE_WINDOW_S, SlaveConfig
from mbgw.errors import ConfigError, ListenError
from mbgw.firewall.guard import Firewall
from mbgw.line.native import stamp_arrivals
from mbgw.net.acl import AccessList
from mbgw.net.address import format_address
from mbgw.net.listen import listen
from mbgw.net.tls import role_of, server_context
from mbgw.ops.counters import Counters, face_counters
from mbgw.ops.limits import (
    FIRST_REQUEST_S,
    SLOW_REQUEST_S,
    AcceptRest,
    WarnLimit,
)
from mbgw.ops.reload import ReloadReport
from mbgw.slave.connections import PEER_GONE, Client, Connections, TlsClient
from mbgw.slave.handshakes import HANDSHAKES_PER_ADDRESS, MAX_HANDSHAKES, Handshakes
from mbgw.slave.rtu_client import RtuClient
from mbgw.slave.udp_face import UdpPort

log = logging.getLogger("mbgw.tcp")

LISTEN_BACKLOG = 100
SWEEP_S = 0.25                   # how often the clients' deadlines are looked at


class Listener:
    def __init__(self, cfg: SlaveConfig, counters: Counters, connections: Connections,
                 firewall: Firewall, on_request=None) -> None:
        """connections: the line thread's, which adopts each client admitted; firewall: the
        rules each client is guarded by at admission (renewed by reconfigure); on_request:
        the router's, for the datagrams of udp-port."""
        self._cfg = cfg
        self.counters = counters
        self.faces = face_counters()     # by listener: plain, tls, udp, rtu
        self._on_request = on_request
        self._rtu_listeners: list[socket.socket] = []
        self.udp_ports: list[UdpPort] = []
        self._connections = connections
        self.firewall = firewall
        self._acl = AccessList(cfg.authip)
        self.clients: list[Client] = []  # the asyncio thread's list, for admission and status
        self._warn = WarnLimit(log)      # refusals: once a minute per address and reason
        self._evictions = WarnLimit(log, level=logging.INFO)
        self._accept_rest = AcceptRest(log, "Modbus TCP")
        self._sweeper: asyncio.TimerHandle | None = None
        self._listeners: list[socket.socket] = []
        self._tls_listeners: list[socket.socket] = []
        self._tls = server_context(cfg.tls) if cfg.tls.enabled else None   # ConfigError
        self._handshakes: Handshakes | None = None     # once the loop runs
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self) -> list[str]:
        """Listen; returns the listening addresses.  Raises ListenError."""
        self._loop = asyncio.get_running_loop()
        self._handshakes = Handshakes(self._loop, self._admit_tls, self._tls_refused,
                                      self._tls_probe)
        self._handshakes.timeout_s = self._cfg.request_timeout_ms / 1000
        self._listen_plain()
        try:
            self._listen_tls()
            self._listen_rtu()
            self._listen_udp()
        except ListenError:
            for listeners in (self._listeners, self._tls_listeners, self._rtu_listeners):
                self._stop_listening(listeners)
            raise
        self._sweeper = self._loop.call_later(SWEEP_S, self._sweep)
        return self.addresses()

    def _listen_plain(self) -> None:
        """Listen on mdbport (0: not at all).  Raises ListenError."""
        self._listeners = self._listen(self._cfg.mdbport, "mdbport", self._accept)

    def _listen_tls(self) -> None:
        """Listen on tls-port while TLS is on.  Raises ListenError."""
        self._tls_listeners = self._listen(self._cfg.tls.port if self._tls is not None else 0,
                                           "tls-port", self._accept_tls)

    def _listen_rtu(self) -> None:
        """Listen on rtu-port (0: not at all).  Raises ListenError."""
        self._rtu_listeners = self._listen(self._cfg.rtu_port, "rtu-port", self._accept_rtu)

    def _listen(self, port: int, option: str, accept) -> list[socket.socket]:
        """Sockets listening on port on bind's addresses (0: none), each read by accept.
        Raises ListenError."""
        assert self._loop is not None
        listeners = listen(self._cfg.bind, port, option=option, stamp_arrivals=stamp_arrivals,
                           backlog=LISTEN_BACKLOG) if port else []
        for sock in listeners:
            self._loop.add_reader(sock.fileno(), accept, sock)
        return listeners

    def _listen_udp(self) -> None:
        """Bind udp-port (0: not at all); the line thread reads it from now on.  Raises
        ListenError."""
        if not self._cfg.udp_port:
            return
        assert self._on_request is not None, "udp-port needs the router's on_request"
        for sock in listen(self._cfg.bind, self._cfg.udp_port, option="udp-port",
                           kind=socket.SOCK_DGRAM):
            port = UdpPort(sock, self._on_request, self._acl, self.firewall,
                           self.faces["udp"], self._cfg.serial.stout_ms)
            self.udp_ports.append(port)
            self._connections.watch(port)

    def addresses(self) -> list[str]:
        return [format_address(s.getsockname()) for s in self._listeners] + \
            [f"{format_address(s.getsockname())} (TLS)" for s in self._tls_listeners] + \
            [f"{format_address(s.getsockname())} (RTU)" for s in self._rtu_listeners] + \
            [f"{p.local} (UDP)" for p in self.udp_ports]

    def _stop_listening(self, listeners: list[socket.socket]) -> None:
        """Stop listening on these: self._listeners (mdbport), _tls_listeners or
        _rtu_listeners."""
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
        for client in list(self.clients):
            if not self._acl.allows(client.host):
                event(log, Kind.CLIENT_CLOSED, "client %s closed: no longer allowed by authip",
                      client.peer, client=client.peer, reason="not in authip")
                self._drop(client)
        if cfg.tls != old.tls or cfg.bind != old.bind:
            self._retls(old, report)
        for port in self.udp_ports:
            port.renew(self._acl, self.firewall, cfg.serial.stout_ms)
        self._relisten_faces(old, report)
        if (cfg.mdbport, cfg.bind) != (old.mdbport, old.bind):
            self._stop_listening(self._listeners)
            try:
                self._listen_plain()
            except ListenError as err:
                where = f"{cfg.bind or '*'} port {cfg.mdbport}"
                for setting in ("mdbport", "bind"):
                    if getattr(cfg, setting) != getattr(old, setting):
                        report.refuse(setting, f"cannot listen on {where} ({err.reason}): "
                                               f"still on port {old.mdbport}")
                self._cfg = dataclasses.replace(self._cfg, mdbport=old.mdbport, bind=old.bind)
                self._listen_plain()
            log.info("now listening on %s", ", ".join(self.addresses()))

    def _relisten_faces(self, old: SlaveConfig, report: ReloadReport) -> None:
        """A new rtu-port listens at once (the connections open stay); a new udp-port waits
        for a restart (the line thread reads its sockets)."""
        cfg = self._cfg
        if (cfg.udp_port, cfg.bind) != (old.udp_port, old.bind) and \
                (cfg.udp_port or old.udp_port):
            report.at_restart("udp-port")
            self._cfg = cfg = dataclasses.replace(cfg, udp_port=old.udp_port)
        if (cfg.rtu_port, cfg.bind) == (old.rtu_port, old.bind):
            return
        self._stop_listening(self._rtu_listeners)
        try:
            self._listen_rtu()
        except ListenError as err:
            report.refuse("rtu-port", f"cannot listen on {cfg.bind or '*'} port "
                                      f"{cfg.rtu_port} ({err.reason}): still on "
                                      f"{old.rtu_port or 'none'}")
            self._cfg = dataclasses.replace(cfg, rtu_port=old.rtu_port)
            self._listen_rtu()

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
        self._stop_listening(self._tls_listeners)
        running, self._tls = self._tls, context
        try:
            self._listen_tls()
        except ListenError as err:
            report.refuse("tls", f"cannot listen on tls-port {new.port} ({err.reason}); "
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
        except ListenError as err:
            log.error("TLS: cannot listen on tls-port %d again (%s): no TLS listener",
                      old.tls.port, err.reason)

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
        for listeners in (self._listeners, self._tls_listeners, self._rtu_listeners):
            self._stop_listening(listeners)
        if self._handshakes is not None:
            self._handshakes.close()
        for client in list(self.clients):
            self._drop(client)

    def _accept(self, listener: socket.socket) -> None:
        self._accept_as(Client, listener, self._accept)

    def _accept_rtu(self, listener: socket.socket) -> None:
        self._accept_as(RtuClient, listener, self._accept_rtu)

    def _accept_as(self, kind: type[Client], listener: socket.socket, handler) -> None:
        """A newcomer on listener (mdbport's, rtu-port's; handler reads it) as a kind client."""
        sock, address = self._accepted(listener, handler)
        if sock is None:
            return
        sock.setblocking(False)
        self._welcome(kind(sock, address[0], format_address(address),
                           format_address(sock.getsockname())))

    def _accepted(self, listener: socket.socket, handler) -> tuple:
        """(socket, address) of a newcomer on listener, or (None, None): none waits, or the
        listener rests (AcceptRest.accept)."""
        accepted = self._accept_rest.accept(listener,
                                            lambda rest_s: self._rest(listener, handler, rest_s))
        return (None, None) if accepted is None else accepted

    def _rest(self, listener: socket.socket, handler, rest_s: float) -> None:
        loop = self._loop
        assert loop is not None
        loop.remove_reader(listener.fileno())
        loop.call_later(rest_s, self._resume, listener, handler)

    def _resume(self, listener: socket.socket, handler) -> None:
        if self._loop is not None and (listener in self._listeners
                                       or listener in self._tls_listeners
                                       or listener in self._rtu_listeners):
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
        self._connections.adopt(client)

    # --- Modbus/TCP Security: accepted here, the handshake in mbgw.slave.handshakes ---

    def _accept_tls(self, listener: socket.socket) -> None:
        sock, address = self._accepted(listener, self._accept_tls)
        if sock is None:
            return
        host = address[0]
        if not self._acl.allows(host):          # before any byte is read
            self.counters.connections_refused_authip += 1
            self.faces["tls"].refused += 1
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
        face = self.faces[client.listener]
        if not self._acl.allows(host):
            self.counters.connections_refused_authip += 1
            face.refused += 1
            self._log_refusal(host, "not in authip")
            return False
        if not self._room_for(client):
            self.counters.connections_refused_limit += 1
            return False
        self.counters.connections_accepted += 1
        client.guard = self.firewall.guard(host, client.role, client.listener)
        client.face = face
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

    def forget_soon(self, client: Client) -> None:
        """Any thread (the line thread, at a connection's end): forget client on the loop."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.forget, client)

    def _log_refusal(self, host: str, reason: str,
                     kind: Kind = Kind.CONNECTION_REFUSED) -> None:
        """Logged at most once a minute per address and reason (with how many were left out):
        a refusal of one kind never hides another kind from the same address."""
        self._warn.warn(host, reason, "connection from %s refused: %s", host, reason,
                        kind=kind, client=host, reason=reason)


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


