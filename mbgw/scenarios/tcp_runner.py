"""The TCP scenarios' runner: a thread of its own that runs the engine's TCP scenarios
(`Scenarios` of kind "tcp") through an UpstreamPool, in every mode.

One poll() loop: it sleeps until the engine's next scenario is due (`due_in`), or a change in
the table made one pending or `scenario test` asks for a run (the engine's `wake_fd`), or the
runner's own eventfd rings (stop, a reload).  A run is one request to its server, with
`tcpto` as the deadline (connecting included), retried after a timeout or a lost connection
(the scenario's `retries`); its reply, or the kind of failure, goes to `engine.done` (a
test's to `engine.test_done`).  Requests go out one at a time (the pool's way), so a server
has at most one in flight.  A server that refuses the connection (or cannot be reached in
`tcpto`) is not tried again before its backoff has passed (doubling from BACKOFF_FIRST_S to
BACKOFF_MAX_S, reset by a reply); its scenarios fail at once meanwhile with the failure that
started it.  A server whose dials fail (no reply within `tcpto`, unreachable, the
connection lost) down-after times in a row is down by the demotion rule of the serial
devices (mbgw.scenarios.health.ServerHealth): its scenarios' runs are skipped, "server
down", but for one probe per probe-interval, which dials whatever the backoff says; a reply
(an exception or a wrong one included) means it is there.  The pool keeps one connection per
server address and port (one pool per port), reopened when the server closes it; `tls`
scenarios' servers have pools of their own, over TLS with the client context made from
[tls]'s client-cert, client-key and server-ca.  The engine is thread-safe: status and
enable come from other threads directly.
"""
import concurrent.futures
import functools
import logging
import math
import os
import select
import ssl
import threading
import time
from collections.abc import Callable
from typing import Any

from mbgw.config.model import UpstreamTlsConfig
from mbgw.config.server_address import split_server
from mbgw.errors import (
    BadReply,
    ConfigError,
    ConnectionLost,
    ConnectTimeout,
    GatewayTimeout,
    HandshakeFailed,
    Interrupted,
    NoRoute,
)
from mbgw.net.tls import client_context
from mbgw.ops.counters import MasterCounters
from mbgw.ops.device_stats import DeviceStats, HealthRule
from mbgw.ops.eventfd import drain
from mbgw.ops.trace import TraceHub
from mbgw.scenarios.engine import Scenarios
from mbgw.scenarios.health import ServerHealth
from mbgw.scenarios.report import scenarios_status, trace_event
from mbgw.upstream.pool import UpstreamPool

log = logging.getLogger("mbgw.scenarios")

MAX_CONNECTIONS = 100           # one per server: at most 100 TCP scenarios
BACKOFF_FIRST_S = 0.25
BACKOFF_MAX_S = 5.0

# the engine's error kinds (mbgw.scenarios.exchange.ERROR_MESSAGES)
TIMEOUT = "timeout"
CONNECTION_LOST = "connection-lost"
CONNECTION_REFUSED = "connection-refused"
UNEXPECTED_DATA = "unexpected-data"
TLS_REFUSED = "tls-refused"     # the handshake failed, or the TLS files cannot be used


class Backoff:
    __slots__ = ("delay_s", "until", "kind")

    def __init__(self) -> None:
        self.delay_s = 0.0
        self.until = 0.0
        self.kind = CONNECTION_REFUSED

    def failed(self, kind: str, now: float) -> None:
        self.delay_s = min(BACKOFF_MAX_S, self.delay_s * 2 or BACKOFF_FIRST_S)
        self.until = now + self.delay_s
        self.kind = kind


class TcpRunner:
    def __init__(self, engine, tcpto_ms: int, clock: Callable[[], float] = time.monotonic,
                 tls: UpstreamTlsConfig | None = None, pins: dict[str, bytes] | None = None,
                 rule: HealthRule | None = None) -> None:
        """pins: the servers whose certificate is pinned (scenario_pins)."""
        self.engine = engine
        self.trace: TraceHub | None = None   # the daemon's trace hub (mbgw.ops.trace), for its runs
        self.health = ServerHealth(rule)       # the servers' demotion, by the engine too
        engine.health = self.health
        self._tcpto_ns = tcpto_ms * 1_000_000
        self._tls = tls or UpstreamTlsConfig()
        self._pins = pins or {}
        self._tls_context: ssl.SSLContext | None = None
        self._clock = clock
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self.counters = MasterCounters()        # the pools' connection figures
        self._pools: dict[tuple[int, bool], UpstreamPool] = {}   # by (port, tls)
        self._backoff: dict[tuple[str, int], Backoff] = {}
        self._calls: list[tuple[Callable[[], Any], concurrent.futures.Future]] = []
        self._lock = threading.Lock()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="mbgw-scenarios-tcp", daemon=True)

    # --- from other threads ---

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopping = True
        for pool in list(self._pools.values()):
            pool.stopping = True
        os.eventfd_write(self._wake_fd, 1)

    def join(self) -> None:
        self._thread.join()
        for pool in self._pools.values():
            pool.close()
        os.close(self._wake_fd)

    def call(self, fn: Callable[[], Any]) -> concurrent.futures.Future:
        """Run fn on the runner's thread between two runs; its result in the future."""
        future: concurrent.futures.Future = concurrent.futures.Future()
        with self._lock:
            self._calls.append((fn, future))
        os.eventfd_write(self._wake_fd, 1)
        return future

    def reconfigure(self, configs, tcpto_ms: int,
                    tls: UpstreamTlsConfig | None = None) -> concurrent.futures.Future:
        """New scenarios, tcpto and TLS files (SIGHUP), applied between two runs."""
        def apply() -> None:
            self._tcpto_ns = tcpto_ms * 1_000_000
            pins = scenario_pins(configs)
            if (tls is not None and tls != self._tls) or pins != self._pins:
                self._tls, self._tls_context = tls or self._tls, None
                self._pins = pins
                for key in [k for k in self._pools if k[1]]:
                    self._pools.pop(key).close()
            self.engine.reconfigure(configs)
            self._backoff.clear()
            self.health.rejudge(time.monotonic())
        return self.call(apply)

    def connections(self) -> list[dict]:
        return [c for pool in list(self._pools.values()) for c in pool.connections()]

    # --- the runner's thread ---

    def _run(self) -> None:
        poller = select.poll()
        poller.register(self._wake_fd, select.POLLIN)
        poller.register(self.engine.wake_fd, select.POLLIN)
        try:
            while not self._stopping:
                self._take_calls()
                now = self._clock()
                self.engine.tick(now)          # stale data, also while runs follow each other
                test = self.engine.take_test(now)
                if test is not None:
                    self.engine.test_done(test, *self.exchange(test.scenario, test.pdu))
                    continue
                run = self.engine.next(now)
                if run is not None:
                    self._execute(run)
                    continue
                poller.poll(self._sleep_ms(now))
                drain(self._wake_fd)       # the engine takes its wake_fd's signal itself
        except Interrupted:
            pass
        except Exception:
            log.exception("the TCP scenarios' runner failed; TCP scenarios stopped")
        self._fail_calls()

    def _sleep_ms(self, now: float) -> int:
        """Until the next run is due (due_in also marks what has gone stale); -1: none is
        planned, the engine's wake_fd or the runner's own eventfd will wake the poll."""
        due = self.engine.due_in(now)
        return -1 if due is None else max(0, math.ceil(due * 1000))

    def _take_calls(self) -> None:
        with self._lock:
            calls, self._calls = self._calls, []
        for fn, future in calls:
            try:
                future.set_result(fn())
            except Exception as err:
                future.set_exception(err)

    def _fail_calls(self) -> None:
        with self._lock:
            calls, self._calls = self._calls, []
        for _, future in calls:
            future.set_exception(RuntimeError("the TCP scenarios' runner has stopped"))

    def _execute(self, run) -> None:
        trace = self.trace
        retrying = functools.partial(self.engine.retrying, run.scenario)
        if trace is None or not trace.active:
            reply, kind, retries = self.exchange(run.scenario, run.pdu, run.probe, retrying)
            self.engine.done(run, reply, kind, retries)
            return
        started = time.monotonic_ns()
        trace.emit_threadsafe(trace_event("request", run.scenario, run.pdu, ""))
        reply, kind, retries = self.exchange(run.scenario, run.pdu, run.probe, retrying)
        result = self.engine.done(run, reply, kind, retries)
        latency_ms = (time.monotonic_ns() - started) / 1e6
        outcome = "ok" if result.ok else result.kind or ""
        if reply is None:
            event = trace_event("no reply", run.scenario, run.pdu[:1], outcome, latency_ms)
        else:
            event = trace_event("reply", run.scenario, bytes(reply), outcome, latency_ms)
        trace.emit_threadsafe(event)

    def exchange(self, scenario, pdu: bytes, probe: bool = False, on_retry=None
                 ) -> tuple[bytes | None, str | None, int]:
        """One run of the scenario's request: (reply PDU, None) or (None or the reply that
        does not answer, error kind), and the retries made; its outcome booked for the
        server's health.  probe: the server is down and this is its probe, which dials even
        within the backoff; on_retry() before each repeat.  Raises Interrupted."""
        host, port = split_server(scenario.server)
        backoff = self._backoff.get((host, port))
        if not probe and backoff is not None and self._clock() < backoff.until:
            return None, backoff.kind, 0
        try:
            pool = self._pool(port, scenario.tls)
        except ConfigError as err:
            log.error("scenario %s: %s", scenario.name, err)
            return None, self._unreachable(host, port, TLS_REFUSED), 0
        server = self.health.of(host, port)
        server.transactions += 1
        started = time.monotonic()
        reply, kind, retries = self._dial(scenario, pool, host, port, pdu, on_retry)
        if kind in (None, UNEXPECTED_DATA):     # a reply came, whatever it said
            exception = reply[1] if reply and reply[0] & 0x80 and len(reply) > 1 else None
            server.answered((time.monotonic() - started) * 1000, exception)
        else:
            self._count_failure(server, kind)
        return reply, kind, retries

    @staticmethod
    def _count_failure(server: DeviceStats, kind: str) -> None:
        if kind == TIMEOUT:
            server.timeouts += 1
        else:
            server.unreachable += 1
        server.failed()

    def _dial(self, scenario, pool: UpstreamPool, host: str, port: int, pdu: bytes,
              on_retry=None) -> tuple[bytes | None, str | None, int]:
        retries = 0
        while True:
            try:
                reply = pool.transact(host, scenario.unit, pdu,
                                      time.monotonic_ns() + self._tcpto_ns)
            except HandshakeFailed:
                return None, self._unreachable(host, port, TLS_REFUSED), retries
            except NoRoute:
                return None, self._unreachable(host, port, CONNECTION_REFUSED), retries
            except ConnectTimeout:
                return None, self._unreachable(host, port, TIMEOUT), retries
            except ConnectionLost:
                kind = CONNECTION_LOST
            except GatewayTimeout:
                kind = TIMEOUT
            except BadReply as err:
                wrong, why = self._bad_reply(err)
                return wrong, why, retries
            else:
                self._backoff.pop((host, port), None)
                return reply, None, retries
            if retries >= scenario.retries:
                return None, kind, retries
            retries += 1
            if on_retry is not None:
                on_retry()

    @staticmethod
    def _bad_reply(err: BadReply) -> tuple[bytes | None, str | None]:
        """A reply that does not answer: the engine tells a wrong function or size from it;
        another unit's reply is wrong data; a bad header has closed the connection."""
        if err.pdu is None:
            return None, CONNECTION_LOST
        if err.counter == "wrong_unit":
            return None, UNEXPECTED_DATA
        return err.pdu, None

    def _unreachable(self, host: str, port: int, kind: str) -> str:
        backoff = self._backoff.setdefault((host, port), Backoff())
        backoff.failed(kind, self._clock())
        return kind

    def _pool(self, port: int, tls: bool) -> UpstreamPool:
        """Raises ConfigError when the TLS files cannot be used."""
        pool = self._pools.get((port, tls))
        if pool is None:
            pool = UpstreamPool(port, MAX_CONNECTIONS, self.counters, self._wake_fd)
            if tls:
                if self._tls_context is None:
                    self._tls_context = client_context(self._tls)
                pool.set_tls(self._tls_context, port, None, self._pins)
            pool.stopping = self._stopping
            self._pools[(port, tls)] = pool
        return pool


def scenario_pins(configs) -> dict[str, bytes]:
    """The pinned certificates of the TLS scenarios' servers, by host."""
    return {split_server(sc.server)[0]: sc.fingerprint for sc in configs
            if sc.tls and sc.fingerprint}


def with_scenarios(collector, engines: dict):
    """The daemon's metrics collector with the scenarios' families (their status rows)."""
    collector.scenarios = lambda: scenarios_status(engines.values())
    return collector


def tcp_scenarios(configs) -> tuple:
    return tuple(sc for sc in configs if sc.kind == "tcp")


class TcpScenarios:
    """A daemon's TCP scenarios (slave and master mode alike): their engine and runner while
    the configuration has any, `engines["tcp"]` meanwhile (the dict the control commands and
    the status read); started, reconfigured and stopped from the asyncio thread."""

    def __init__(self, table, engines: dict, rule: HealthRule | None = None,
                 trace=None) -> None:
        self.table = table
        self.engines = engines
        self.rule = rule           # the mode's demotion settings (down-after, probe-interval)
        self.trace = trace         # the daemon's trace hub: the runs are traced
        self.runner: TcpRunner | None = None

    def start(self, configs, tcpto_ms: int, tls: UpstreamTlsConfig | None = None) -> None:
        configs = tcp_scenarios(configs)
        if configs:
            engine = Scenarios(configs, self.table, "tcp")
            self.runner = TcpRunner(engine, tcpto_ms, tls=tls, pins=scenario_pins(configs),
                                    rule=self.rule)
            self.runner.trace = self.trace
            self.runner.start()
            self.engines["tcp"] = engine
            log.info("%d TCP scenarios, tcpto %d ms", len(configs), tcpto_ms)

    def reconfigure(self, configs, tcpto_ms: int, tls: UpstreamTlsConfig | None = None) -> None:
        """New settings (SIGHUP): the runner started, given its new scenarios, or stopped."""
        configs = tcp_scenarios(configs)
        if self.runner is None:
            self.start(configs, tcpto_ms, tls)
        elif not configs:
            self.stop()
            log.info("no TCP scenarios any more")
        else:
            self.runner.reconfigure(configs, tcpto_ms, tls).result()

    def stop(self) -> None:
        runner, self.runner = self.runner, None
        if runner is not None:
            self.engines.pop("tcp", None)
            runner.stop()
            runner.join()
            runner.engine.close()
