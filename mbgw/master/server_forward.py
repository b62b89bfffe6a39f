"""A serial face's requests to Modbus TCP servers, on the face's own thread: one upstream
pool per servers' port (TLS where the slaveid table or a route asks for it), the request
forwarded to its unit id with tcpto as the deadline, an address that is down refused
without a word to its server (unless a probe is due), and a broadcast sent to every server
the face reaches.  The face answers the master (`SerialFace._reply`).
"""
import logging
import time
from collections.abc import Callable

from mbgw.errors import BadReply, ConfigError, GatewayTimeout, NoRoute
from mbgw.master.face_routes import SERVER, FaceSettings, Hop, ports
from mbgw.master.trace import MasterTracer
from mbgw.net.ratelimit import RateLimitedLog
from mbgw.ops.counters import MasterCounters
from mbgw.ops.device_stats import DeviceHealth, DeviceStats
from mbgw.ops.trace import Outcome, TraceHub
from mbgw.protocol import pdu
from mbgw.upstream.pool import UpstreamPool
from mbgw.upstream.tls_choice import ClientTls, routes_tls

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")

# SerialFace._reply: (adu, reply, exception code, stats, outcome, quiet_ms) -> the outcome
Reply = Callable[[bytes, bytes | None, int | None, DeviceStats, str, int], str]


class ServerForward:
    def __init__(self, counters: MasterCounters, devices: DeviceHealth, hub: TraceHub,
                 tracer: MasterTracer, wake_fd: int, reply: Reply) -> None:
        """wake_fd: the face's eventfd, which the pools' waits poll; reply: how the face
        answers the master."""
        self._counters = counters
        self._devices = devices
        self._down = devices.rule.down    # the addresses that are down, by address
        self.trace = hub              # .active: one attribute test on the request's path
        self._tracer = tracer
        self._wake_fd = wake_fd
        self._reply = reply
        self._pools: dict[int, UpstreamPool] = {}
        self._tls = ClientTls()
        self._bad_reply_log = RateLimitedLog()      # by (address, kind of bad reply)
        self.stopping = False

    def pool(self, port: int) -> UpstreamPool:
        """The pool of the servers on port (one of `ports(cfg)` after use)."""
        return self._pools[port]

    def use(self, old: FaceSettings | None, cfg: FaceSettings) -> None:
        """One upstream pool per servers' port (the old ones for ports no longer reached
        closed), each reached over TLS as cfg says; a TLS error keeps the previous
        certificates, but for the first settings (old None): ConfigError."""
        pools = {}
        for port in ports(cfg):
            pool = self._pools.get(port)
            if pool is None:
                pool = UpstreamPool(port, cfg.max_connections, self._counters, self._wake_fd)
                pool.on_late = self._late
                pool.stopping = self.stopping
            else:
                pool.reconfigure(port, cfg.max_connections)
            pools[port] = pool
        for port, pool in self._pools.items():
            if port not in pools:
                pool.close()
        self._pools = pools
        try:
            self._use_tls(cfg)
        except ConfigError as err:
            if old is None:
                raise
            log.error("TLS to servers: %s: the previous certificates stay in use", err)

    def _use_tls(self, cfg: FaceSettings) -> None:
        """The servers of the slaveid table's `tls` ranges (on tls server-port) and of the
        `tls = true` routes (on their own port) reached over TLS (upstream.tls_choice).
        Raises ConfigError."""
        upstream, slaveid = cfg.upstream_tls, cfg.slaveid
        for port, pool in self._pools.items():
            if slaveid is not None and port == cfg.mdbport:
                self._tls.reach(pool, upstream, upstream.server_port, slaveid.tls_hosts,
                                slaveid.pins)
            else:
                self._tls.reach(pool, upstream, port, *routes_tls(cfg.routes, port))

    def connections(self) -> list[dict]:
        """The open upstream connections (from any thread)."""
        return [c for pool in list(self._pools.values()) for c in pool.connections()]

    def stop(self) -> None:
        """From another thread: the pools' waits end."""
        self.stopping = True
        for pool in list(self._pools.values()):
            pool.stopping = True

    def close(self) -> None:
        """The connections released at once."""
        for pool in self._pools.values():
            pool.close()

    def forward(self, adu: bytes, hop: Hop, received_ns: int, tcpto_ns: int,
                quiet_ms: int) -> None:
        """The request taken off the line at received_ns to its server, and the master
        answered; quiet_ms: the line's quiet before an answer given at once."""
        self._counters.requests += 1
        stats = self._devices.get(adu[0])
        if stats.upstream != hop.upstream:
            stats.upstream = hop.upstream
        if self._down[adu[0]] and not stats.admit(time.monotonic()):
            self._refuse_as_down(adu, stats, hop, quiet_ms)
            return
        stats.transactions += 1
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("line rx %s -> %s unit %d", adu.hex(" "), hop.host, hop.unit)
        server = hop.label if self.trace.active else ""
        on_sent = sent = None
        if server:
            sent = []

            def on_sent(conn, tid: int) -> None:
                sent.append((conn, tid))
                self._tracer.request(adu, server, conn, tid, hop.unit)
        reply, reply_unit, code, outcome = self._transact(adu, hop, stats, received_ns,
                                                          received_ns + tcpto_ns, on_sent)
        latency_ms = (time.monotonic_ns() - received_ns) / 1e6
        outcome = self._reply(adu, reply if code is None else None, code, stats, outcome, 0)
        if server:
            self._tracer.outcome(adu, server, sent[0] if sent else None, reply_unit, reply,
                                 outcome, None if reply is None else latency_ms)

    def _transact(self, adu: bytes, hop: Hop, stats: DeviceStats, received_ns: int,
                  deadline_ns: int, on_sent):
        """(the server's reply or None, its unit, the exception code to answer or None,
        the outcome)."""
        try:
            reply = hop.pool.transact(hop.host, hop.unit, adu[1:], deadline_ns, on_sent)
        except GatewayTimeout:
            self._counters.timeouts += 1
            stats.timeouts += 1
            stats.failed()
            return None, hop.unit, pdu.GATEWAY_TARGET_FAILED, Outcome.TIMEOUT
        except NoRoute:
            self._counters.unreachable += 1
            stats.unreachable += 1
            stats.failed()
            return None, hop.unit, pdu.GATEWAY_PATH_UNAVAILABLE, Outcome.UNREACHABLE
        except BadReply as err:
            self._bad_reply(stats, hop, err)
            # the server's frame, if any, for the trace
            return (err.pdu, err.unit if err.pdu is not None else hop.unit,
                    pdu.GATEWAY_TARGET_FAILED, f"{Outcome.BAD_REPLY}: {err}")
        exception = reply[0] & pdu.EXCEPTION_FLAG
        if exception:
            self._counters.device_exceptions += 1
        stats.answered((time.monotonic_ns() - received_ns) / 1e6,
                       reply[1] if exception and len(reply) > 1 else None)
        return reply, hop.unit, None, Outcome.SERVER_EXCEPTION if exception else Outcome.REPLY

    def _late(self, conn, tid: int, unit: int, reply: bytes) -> None:
        """A pool dropped a late reply (an earlier request's tid)."""
        if self.trace.active:
            pool = self._pools.get(conn.port)
            server = pool.server(conn.host) if pool is not None else f"{conn.host}:{conn.port}"
            self._tracer.late(server, conn, tid, unit, reply)

    def _refuse_as_down(self, adu: bytes, stats: DeviceStats, hop: Hop, quiet_ms: int) -> None:
        """The address is down and this is no probe: nothing goes to its server, the master
        gets 0x0B once the line has been quiet for t3.5 (with `exception`), else nothing."""
        self._counters.demoted_rejects += 1
        outcome = self._reply(adu, None, pdu.GATEWAY_TARGET_FAILED, stats, Outcome.DEVICE_DOWN,
                              quiet_ms)
        if self.trace.active:
            self._tracer.outcome(adu, hop.label, None, hop.unit, None, outcome, None)

    def _bad_reply(self, stats, hop: Hop, err: BadReply) -> None:
        """Counted as the device's failure; a warning per address and kind of bad reply, at
        most once a minute (before the health change it may bring)."""
        setattr(stats, err.counter, getattr(stats, err.counter) + 1)
        left_out = self._bad_reply_log.due((stats.address, err.counter))
        if left_out is not None:
            log.warning("device %d: the reply of server %s unit %d does not answer the "
                        "request (%s): dropped (replies of this kind for this address are "
                        "logged at most once a minute%s)", stats.address, hop.label, hop.unit,
                        err, f"; {left_out} left out since the last" if left_out else "")
        stats.failed()

    def broadcast(self, adu: bytes, hops: list[Hop | None], tcpto_ns: int,
                  tracer: MasterTracer | None) -> tuple[int, int]:
        """Address 0's request with unit id 0 to every server of hops: (how many it
        reached, how many there are)."""
        servers: dict[int, dict[str, None]] = {}
        for hop in hops:
            if hop is not None and hop.kind == SERVER:
                servers.setdefault(hop.port, {})[hop.host] = None
        on_sent = None
        if tracer is not None:
            def on_sent(conn, tid: int) -> None:
                tracer.request(adu, f"{conn.host}:{conn.port}", conn, tid, pdu.BROADCAST)
        deadline_ns = time.monotonic_ns() + tcpto_ns
        reached = total = 0
        for port, hosts in servers.items():
            total += len(hosts)
            reached += self._pools[port].send_all(hosts, pdu.BROADCAST, adu[1:], deadline_ns,
                                                  on_sent)
        return reached, total
