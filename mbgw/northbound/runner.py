"""Northbound MQTT on the daemon's asyncio loop: a session to the broker, reopened after 1 s,
doubling to 60 s, and a tick that hands the profile the table's latest values.  Nothing is
queued while the broker is away: the births after reconnecting carry the latest values."""
import asyncio
import logging
from collections.abc import Callable

from mbgw.config.mqtt import MqttConfig
from mbgw.firewall.guard import Firewall
from mbgw.net.tls import broker_context
from mbgw.northbound import catalogue
from mbgw.northbound.commands import Writes
from mbgw.northbound.connection import Session
from mbgw.northbound.counters import NorthboundCounters
from mbgw.northbound.edge_node import EdgeNode
from mbgw.northbound.json_node import JsonNode
from mbgw.northbound.names import default_node
from mbgw.northbound.sampler import Sampler

log = logging.getLogger("mbgw.northbound")

TICK_S = 0.1                       # a demoted device's DDEATH well within 1 s
BACKOFF_S = (1.0, 60.0)            # the first reconnect delay, and the longest


class Northbound:
    """Publishes `scenarios`' data from `table` to the broker of `cfg`.  lines() gives each
    line's state by name; engines: the scenarios' engines by kind (their health, data age,
    and the runner a write goes through)."""

    def __init__(self, cfg: MqttConfig, scenarios, table, engines: dict,
                 lines: Callable[[], dict[str, str]], firewall: Firewall,
                 client_tls=None) -> None:
        self.cfg = cfg
        self.node = cfg.node or default_node()
        self.lines = lines
        self.counters = NorthboundCounters(broker=cfg.broker or "", node=self.node,
                                           profile=cfg.profile)
        devices = catalogue.devices(scenarios)
        sampler = Sampler(table, engines, cfg.stale_after_ms)
        self.profile: EdgeNode | JsonNode = \
            EdgeNode(cfg, self.node, devices, sampler, self.counters) \
            if cfg.profile == "sparkplug" else \
            JsonNode(cfg, self.node, devices, sampler, self.counters)
        self.writes = Writes(cfg.role, firewall, devices, engines, self.counters)
        self._context = _context(cfg, client_tls) if cfg.tls else None
        self._task: asyncio.Task | None = None
        self._session: Session | None = None
        self._lost = asyncio.Event()
        self._pending: set[asyncio.Task] = set()

    def start(self) -> None:
        log.info("mqtt: %s node %s (%s), group %s", self.cfg.broker, self.node,
                 self.cfg.profile, self.cfg.group)
        self._task = asyncio.ensure_future(self._run())

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        session = self._session
        if session is not None:
            self.profile.farewell(session)
            await session.close()
        self.counters.connected = False

    def status(self) -> dict:
        return self.counters.snapshot()

    async def _run(self) -> None:
        delay = BACKOFF_S[0]
        loop = asyncio.get_running_loop()
        while True:
            self._lost.clear()
            session = Session(self.cfg.broker or "", self.node, self._context, loop,
                              self._message, self._lost.set)
            self.profile.will(session)
            self._session = session
            why = await session.open()
            if why is not None:
                log.warning("mqtt: %s: %s; again in %g s", self.cfg.broker, why, delay)
                self._session = None
                await session.close()
                await asyncio.sleep(delay)
                delay = min(delay * 2, BACKOFF_S[1])
                continue
            delay = BACKOFF_S[0]
            self.counters.connected = True
            self.counters.connects += 1
            log.info("mqtt: connected to %s", self.cfg.broker)
            for topic, qos in self.profile.subscriptions():
                session.subscribe(topic, qos)
            self.profile.connected(session)
            await self._serve(session)
            self.counters.connected = False
            self._session = None
            if self.profile.leave:
                self.profile.farewell(session)
                log.info("mqtt: the primary host is offline: session ended")
            else:
                log.warning("mqtt: lost %s; again in %g s", self.cfg.broker, delay)
            await session.close()
            await asyncio.sleep(delay)
            delay = min(delay * 2, BACKOFF_S[1])

    async def _serve(self, session: Session) -> None:
        """A tick every TICK_S, at a fixed rate (a slow tick does not shift the next ones),
        until the session is lost."""
        loop = asyncio.get_running_loop()
        due = loop.time()
        while not self._lost.is_set() and not self.profile.leave:
            self.profile.tick(session, self.lines())
            due = max(due + TICK_S, loop.time())
            try:
                await asyncio.wait_for(self._lost.wait(), due - loop.time())
            except TimeoutError:
                pass

    def _message(self, topic: str, payload: bytes) -> None:
        for device, name, value in self.profile.message(topic, payload):
            task = asyncio.ensure_future(self.writes.write(device, name, value))
            self._pending.add(task)
            task.add_done_callback(self._pending.discard)


def _context(cfg: MqttConfig, client_tls):
    """mqtts: the [mqtt] keys, else the [tls] client certificate and CA."""
    cert, key, ca = cfg.cert, cfg.key, cfg.ca
    if cert is None and client_tls is not None and client_tls.enabled:
        cert, key = client_tls.client_cert, client_tls.client_key
    if ca is None and client_tls is not None and client_tls.enabled:
        ca = client_tls.server_ca
    return broker_context(cert, key, ca)
