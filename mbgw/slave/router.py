"""Slave mode's requests from Modbus TCP clients, on the thread that holds the line thread's
gate: routed, answered at once or queued for the line, and their outcomes sent back.

The line thread's Connections calls request() for each frame it reads and the line thread
finished() with each outcome: one thread carries a transaction from the client's bytes to the
reply.  Each request is checked against its client's firewall rule first.

With the exchange table on, a request for it (its unit's hop, TABLE) is answered at once by the
thread that read it: the line thread, or while that thread is in a serial transaction the
table reader (mbgw.slave.table_reader), which calls read_meanwhile() and keeps the requests
for the line for the line thread (take_kept).  Both hold the line thread's gate meanwhile.

Each unit's hop (mbgw.slave.routes) says where its request goes: today's way to line serial,
the table, line serial with the unit rewritten, nowhere (0x0A or silence), or another target
(a line, a remote server) as an Exchange in its Inbox.  That target's thread hands the
outcome back through a deque; it delivers it itself while the face's thread is idle (it then
holds the connections' home), else the wake-up eventfd tells whoever holds the gate to
(deliver_completions): a client is only ever touched by one thread at a time.
"""
import time
from collections import deque

from mbgw.config.cache import CacheRule
from mbgw.config.lines import PRIMARY_LINE
from mbgw.config.model import SlaveConfig
from mbgw.firewall.guard import Firewall, Guard
from mbgw.line import native
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.trace import Outcome, TraceEvent, TraceHub
from mbgw.protocol import pdu
from mbgw.routing.cache import ReadCache, is_read, resolve
from mbgw.routing.queue import Exchange, Inbox, Job, Scheduler
from mbgw.slave.connections import Client, Connections
from mbgw.slave.routes import (
    DIRECT,
    GATEWAY,
    SERIAL,
    TABLE,
    Hop,
    answered_off_the_line,
    effective_routes,
    face_hops,
    is_today,
)

OUTCOME_FIREWALL = Outcome.FIREWALL    # refused by the firewall (0x01)


class Router:
    def __init__(self, cfg: SlaveConfig, scheduler: Scheduler, counters: Counters,
                 line_up, devices: DeviceHealth, firewall: Firewall, trace: TraceHub,
                 table=None, inboxes: dict[str, Inbox] | None = None) -> None:
        """line_up: callable, is the serial line usable?  table: the exchange table
        (mbgw.table.memory.Table), served while cfg.table is enabled.  inboxes: the other
        targets' (lines by name, servers by target label), a dict the daemon keeps up to
        date before each reload."""
        self._cfg = cfg
        self._scheduler = scheduler
        self.counters = counters
        self._line_up = line_up
        self._devices = devices
        self._down = devices.rule.down   # the addresses that are down, by address
        self.firewall = firewall         # swapped whole at a reload
        self.trace = trace
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
        # The face's connections (TcpServer sets them): their home lets a target's thread
        # deliver while the face's own thread is idle
        self.connections: Connections | None = None
        # What the face answered off line serial (the table, another line, unroutable, the
        # firewall), also in counters, the daemon's totals: line serial's own figures are
        # the difference (mbgw.slave.line_share)
        self.off_line = Counters()
        # line serial's reads (mbgw.routing.cache): the line thread's too
        self.cache = ReadCache()

    def route_face(self, cfg: SlaveConfig) -> None:
        """The face's hops for cfg, swapped whole.  At a reload the line thread calls it
        between two turns (SlaveLineThread._configure), so that the C shortcut never takes a
        request the new routes send elsewhere."""
        face = face_hops(effective_routes(cfg), self.inboxes, self.table is not None)
        self.shortcut_allowed = is_today(face) and not cfg.table_on
        self.reads_meanwhile = answered_off_the_line(face)
        self._face = face
        for inbox in list(self.inboxes.values()):
            if inbox.loans is not None:     # the units its lent clients' requests may take
                inbox.loans.route(face)

    def reconfigure(self, cfg: SlaveConfig, firewall: Firewall) -> None:
        """Asyncio thread, at a reload: the settings and the firewall requests are checked
        against from now on (the routes follow in route_face, on the line thread)."""
        self._cfg = cfg
        self.firewall = firewall

    # --- the line thread: requests in, outcomes out ---

    def request(self, client: Client, tid: int, unit: int, request: bytes,
                received_ns: int = 0) -> None:
        """A request read from client, which arrived at received_ns (0: client.arrived_ns)."""
        received_ns = received_ns or client.arrived_ns
        if not self._allowed(client, tid, unit, request, received_ns):
            return
        hop = self._face[unit]
        if hop is DIRECT:
            job = self._admit(client, tid, unit, request, received_ns, 0, self._cfg.cache)
            if job is not None:
                client.admitted()
                self._scheduler.submit(client.queue, job)
            return
        self._elsewhere(hop, client, tid, unit, request, received_ns, self._responder)

    def _allowed(self, client: Client, tid: int, unit: int, request: bytes,
                 received_ns: int) -> bool:
        """The request counted for its client; False when the client's rule refused it (it
        is answered already)."""
        client.requests += 1
        client.face.requests += 1
        guard = client.guard
        if guard is None or guard.allows(unit, request):
            return True
        self._refused_by_firewall(client, guard, tid, unit, request, received_ns)
        return False

    def _requested(self, client: Client, tid: int, unit: int, request: bytes,
                   line: str | None = PRIMARY_LINE) -> bool:
        """A request counted, and traced while someone traces: whether they do."""
        self.counters.requests += 1
        if self.trace.active:
            self.trace.emit_threadsafe(self._event("request", client, tid, unit, request, "",
                                                   None, line))
            return True
        return False

    def _elsewhere(self, hop: Hop | None, client: Client, tid: int, unit: int,
                   request: bytes, received_ns: int, responder) -> None:
        """A request the face's routes take elsewhere than today's way to line serial."""
        off_line = self.off_line
        if hop is None:
            self._requested(client, tid, unit, request, None)
            self.counters.unroutable += 1
            off_line.requests += 1
            off_line.unroutable += 1
            if self._cfg.exception:          # as gateway_exception counts
                off_line.gateway_exceptions += 1
            if self._refuse(client, tid, unit, request, Outcome.UNROUTABLE, received_ns,
                            line=None):
                off_line.replies += 1
            return
        kind = hop.kind
        if kind is TABLE:
            self._from_table(client, tid, unit, request, responder,
                             hop.rewrite(unit) == pdu.BROADCAST)
        elif kind is GATEWAY:
            self._from_table(client, tid, unit, request, responder, False, identity=True)
        elif kind is SERIAL:
            job = self._admit(client, tid, unit, request, received_ns, hop.rewrite(unit),
                              resolve(hop.cache, self._cfg.cache))
            if job is not None:
                client.admitted()
                self._scheduler.submit(client.queue, job)
        else:
            self._requested(client, tid, unit, request, hop.line)
            off_line.requests += 1
            inbox = hop.inbox
            assert inbox is not None
            client.admitted()
            exchange = Exchange(client, hop.rewrite(unit), request, received_ns,
                                self._completed, (client, tid, unit, hop.line), hop.cache)
            if inbox.loans is not None and type(client) is Client and not hop.cache:
                exchange.loan_to = inbox.loans      # its next requests, if it stays at rest
            inbox.submit(exchange)

    def _completed(self, exchange: Exchange, reply: bytes | None, outcome: str) -> None:
        """The target's thread: the outcome waits for the thread that holds the gate (the
        client is touched by no other), unless that thread is idle: then this one takes the
        connections' home and delivers it (with any outcome waiting before it, in order).
        The face's thread is woken when it is busy, or when a client changed meanwhile
        (its output backed up, room for requests again) so that it polls it anew."""
        self._completions.append((exchange, reply, outcome))
        connections = self.connections
        if connections is not None and connections.home.acquire(False):
            try:
                self.deliver_completions()
                settled = connections.settled
            finally:
                connections.home.release()
            if settled:
                return
        self._scheduler.wake()

    def deliver_completions(self) -> None:
        """Under the gate (the line thread, or the table reader): the other lines' outcomes
        to their clients, under the client's own transaction id and unit."""
        completions = self._completions
        while completions:
            exchange, reply, outcome = completions.popleft()
            client, tid, unit, line = exchange.context
            if exchange.taken:
                self._taken_by_target(client, tid, unit, exchange.pdu, line)
            forwarded = exchange.forwarded
            client.answered(forwarded)
            if self._answer(client, tid, unit, reply, forwarded):
                self.off_line.replies += 1
            if self.trace.active:
                self.traced(client, tid, unit, exchange.pdu[0], reply, outcome,
                            exchange.received_ns, line)
            loans = exchange.loan_to
            if loans is not None and loans.open and client.at_rest and not client.lent \
                    and client.guard is None and self.connections is not None:
                self.connections.lend(client, loans, self._completed)

    def _taken_by_target(self, client: Client, tid: int, unit: int, request: bytes,
                         line: str | None) -> None:
        """A request a remote line's thread read from a lent client and took (see
        mbgw.slave.loans), counted as request() counts one."""
        client.requests += 1
        client.face.requests += 1
        client.last_active = time.monotonic()
        self._requested(client, tid, unit, request, line)
        self.off_line.requests += 1

    # --- the table reader, under the gate while the line thread is in a serial transaction

    def read_meanwhile(self, client: Client, tid: int, unit: int, request: bytes,
                       responder) -> None:
        """A request the table reader read: a table request is answered now (with the
        reader's own responder); one for the line is kept for the line thread, in flight
        already so that the client's limit of requests in the gateway holds."""
        hop = self._face[unit]
        if hop is not None and hop.kind is SERIAL:
            client.admitted()
            self._kept.append((client, tid, unit, request, client.arrived_ns))
            return
        if self._allowed(client, tid, unit, request, client.arrived_ns):
            self._elsewhere(hop, client, tid, unit, request, client.arrived_ns, responder)

    def take_kept(self) -> None:
        """Line thread, under the gate: route the requests the table reader kept for the line,
        in the order they were read."""
        kept = self._kept
        if not kept:
            return
        for client, tid, unit, request, received_ns in kept:
            client.answered()
            if not client.closed:
                self.request(client, tid, unit, request, received_ns)
        kept.clear()

    def _from_table(self, client: Client, tid: int, unit: int, request: bytes,
                    responder, broadcast: bool, identity: bool = False) -> None:
        """Answer a request from the exchange table at once; unit 0 is a broadcast into it
        (direct messaging off), with no reply.  identity: the gateway unit's request, which
        only the identity functions answer."""
        tracing = self._requested(client, tid, unit, request)
        if identity:
            reply = responder.answer_identity(request)
        elif broadcast:
            reply = responder.answer(request, broadcast=True)
        else:
            reply = responder.answer(request)
        self.off_line.requests += 1
        if self._answer(client, tid, unit, reply):
            self.off_line.replies += 1
        if tracing:
            self.traced(client, tid, unit, request[0], reply, Outcome.TABLE, client.arrived_ns,
                        None)

    def _refused_by_firewall(self, client: Client, guard: Guard, tid: int, unit: int,
                             request: bytes, received_ns: int) -> None:
        """A request the client's rule does not allow: 0x01 (a broadcast's too: it was not
        done); it reaches neither the line nor the table."""
        client.firewall_refused += 1
        client.face.refused += 1
        tracing = self._requested(client, tid, unit, request)
        reply = self.firewall.refused(guard, client.peer, client.role, unit, request)
        self.off_line.requests += 1
        if self._answer(client, tid, unit, reply):
            self.off_line.replies += 1
        if tracing:
            self.traced(client, tid, unit, request[0], reply, Outcome.FIREWALL, received_ns,
                        None)

    def taken(self, client: Client, tid: int, unit: int, request: bytes,
              received_ns: int) -> Job | None:
        """A request the line thread put on the idle line itself (its shortcut, which takes
        only what routes, never for an address that is down) after it arrived at
        received_ns, counted, checked and traced as request() does; the client has it in
        flight and counted already."""
        return self._admit(client, tid, unit, request, received_ns)

    def _admit(self, client: Client, tid: int, unit: int, request: bytes,
               received_ns: int, address: int = 0, rule: CacheRule | None = None
               ) -> Job | None:
        """The job for a request that arrived at received_ns, or None when it was answered
        at once (it cannot reach the line, its address is down and this is no probe: it
        must not wait in the queue for a refusal, or a read its cache rule answers)."""
        self._requested(client, tid, unit, request)
        address = address or self._cfg.slaveid or unit
        if address > pdu.MAX_SERIAL_ADDRESS:
            self.counters.unroutable += 1
            self._refuse(client, tid, unit, request, Outcome.UNROUTABLE, received_ns)
            return None
        adu = bytes((address,)) + request
        if rule is not None and is_read(adu):
            if self._from_cache(client, tid, unit, adu, received_ns,
                                self.cache.answer(rule, adu, received_ns, time.monotonic_ns())):
                return None
        else:
            rule = None
        if not self._line_up():
            self.counters.line_down_rejects += 1
            self._refuse(client, tid, unit, request, Outcome.LINE_DOWN, received_ns)
            return None
        down = self._down[address] == 1
        if down:
            device = self._devices.get(address)
            if not device.admit(time.monotonic()):
                if rule is not None and self._from_cache(
                        client, tid, unit, adu, received_ns,
                        self.cache.stale(rule, adu, time.monotonic_ns())):
                    return None
                self.counters.demoted_rejects += 1
                self._refuse(client, tid, unit, request, Outcome.DEVICE_DOWN, received_ns,
                             pdu.GATEWAY_TARGET_FAILED, device)
                return None
        return Job(client, tid, unit, adu, received_ns, probe=down, cache=rule)

    def _from_cache(self, client: Client, tid: int, unit: int, adu: bytes, received_ns: int,
                    reply: bytes | None) -> bool:
        """A read answered from the line's cache (reply: what it found), at once under the
        client's own tid; False when it found nothing."""
        if reply is None:
            return False
        self._answer(client, tid, unit, reply)
        if self.trace.active:
            self.traced(client, tid, unit, adu[1], reply, self.cache.outcome(), received_ns)
        return True

    def finished(self, job: Job, reply: bytes | None, forwarded: int = -1) -> None:
        """job's outcome: its reply (if any) goes out at once, or its rest when the serial
        receive forwarded that many bytes of it already."""
        client = job.client
        client.answered(forwarded)
        self._answer(client, job.tid, job.unit, reply, forwarded)
        if self.trace.active:
            self.traced(client, job.tid, job.unit, job.adu[1], reply, job.outcome,
                        job.received_ns)

    def closed(self, client: Client) -> None:
        """Line thread: client's connection has ended; its queued requests go."""
        self._scheduler.discard(client.queue)

    def _answer(self, client: Client, tid: int, unit: int, reply: bytes | None,
                forwarded: int = -1) -> bool:
        """Whether a reply was counted (sent, or forwarded by C already: counted even if
        the client has closed since, before these books)."""
        if reply is None:
            return False
        whole = forwarded >= native.HEADER_LEN + len(reply)
        if client.closed and not whole:
            return False
        if not whole:
            client.send(native.frame(tid, unit, reply)[max(forwarded, 0):])
        if not client.closed:
            client.last_active = time.monotonic()
        self.counters.replies += 1
        return True

    def _refuse(self, client: Client, tid: int, unit: int, request: bytes, outcome: str,
                received_ns: int, code: int = pdu.GATEWAY_PATH_UNAVAILABLE,
                device=None, line: str | None = PRIMARY_LINE) -> bool:
        """Whether a reply was sent."""
        reply = gateway_exception(self._cfg.exception, request[0], code, self.counters,
                                  device)
        sent = self._answer(client, tid, unit, reply)
        if self.trace.active:
            self.traced(client, tid, unit, request[0], reply, outcome, received_ns, line)
        return sent

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
                "face": client.listener,
                "tid": tid, "unit": unit,
                "function": data[0], "length": len(data) if direction != "no reply" else 0,
                "pdu": data.hex() if direction != "no reply" else "", "outcome": outcome,
                "latency_ms": latency_ms}
