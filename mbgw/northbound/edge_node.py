"""The Sparkplug B 3.0 edge node: what it publishes in a session and when (births once per
session, data by exception, a device's death when it is demoted and its birth when it
answers again), the seq and bdSeq rules, and the primary host's STATE."""
import logging

from mbgw.config.mqtt import MqttConfig
from mbgw.northbound import sparkplug
from mbgw.northbound.catalogue import Device
from mbgw.northbound.connection import Session
from mbgw.northbound.counters import NorthboundCounters
from mbgw.northbound.sampler import Reading, Sampler, moved

log = logging.getLogger("mbgw.northbound")

DOWN = "down"
Write = tuple[str, str, object]        # (device id, metric name, value)


class EdgeNode:
    """One profile of the runner (mbgw.northbound.runner): Sparkplug B."""

    def __init__(self, cfg: MqttConfig, node: str, devices: dict[str, Device],
                 sampler: Sampler, counters: NorthboundCounters) -> None:
        self.cfg = cfg
        self.group = cfg.group
        self.node = node
        self.devices = devices
        self.sampler = sampler
        self.counters = counters
        self.bdseq = 0                 # the next CONNECT's
        self._session_bdseq = 0
        self.seq = 0
        self.host_online = cfg.primary_host is None
        self.leave = False             # end this session (the primary host went offline)
        self._born_node = False
        self._born: set[str] = set()
        self._published: dict[str, dict[str, Reading]] = {}
        self._health: dict[str, str] = {}
        self._lines: dict[str, str] = {}

    # --- the session ---

    def will(self, session: Session) -> None:
        """The Will of the next CONNECT: NDEATH with a new bdSeq (+1 mod 256 each CONNECT)."""
        self._session_bdseq = self.bdseq
        self.bdseq = (self.bdseq + 1) % 256
        session.will(self._topic("NDEATH"), sparkplug.death(self._session_bdseq), 1, False)

    def subscriptions(self) -> list[tuple[str, int]]:
        topics = [(self._topic("NCMD"), 1), (self._topic("DCMD") + "/+", 1)]
        if self.cfg.primary_host is not None:
            topics.append((sparkplug.state_topic(self.cfg.primary_host), 1))
        return topics

    def connected(self, session: Session) -> None:
        """A new session: nothing of the last one was born in this one, and the primary
        host's STATE is to be heard again (the broker keeps it retained)."""
        self._born_node = False
        self._born.clear()
        self.host_online = self.cfg.primary_host is None
        self.leave = False

    def farewell(self, session: Session) -> None:
        """Before a disconnect of our own: the death the Will would have been."""
        session.publish(self._topic("NDEATH"), sparkplug.death(self._session_bdseq), qos=1)

    # --- each tick, on the loop ---

    def tick(self, session: Session, lines: dict[str, str]) -> None:
        self.sampler.begin()
        if not self.host_online:
            return
        if not self._born_node:
            self._birth_node(session, lines)
        elif lines != self._lines:
            changed = {n: s for n, s in lines.items() if self._lines.get(n) != s}
            if self._send(session, self._topic("NDATA"), sparkplug.node_data(self.seq, changed),
                          len(changed)):
                self._lines = dict(lines)
                self.counters.lines = self._lines
        for device in self.devices.values():
            self._device(session, device)

    def rebirth(self) -> None:
        """NCMD Node Control/Rebirth: every birth again, at the next tick."""
        self._born_node = False

    def _birth_node(self, session: Session, lines: dict[str, str]) -> None:
        self.seq = 0
        self._born.clear()
        session.publish(self._topic("NBIRTH"),
                        sparkplug.node_birth(self.seq, self._session_bdseq, lines))
        self.counters.sent += 1
        self.seq = 1
        self._lines = dict(lines)
        self.counters.lines = self._lines
        self._born_node = True

    def _device(self, session: Session, device: Device) -> None:
        health = self.sampler.health(device)
        if health == DOWN:
            if device.id in self._born and self._send(
                    session, self._topic("DDEATH", device.id), sparkplug.bare(self.seq), 1):
                self._born.discard(device.id)
            return
        readings = self.sampler.readings(device)
        if device.id not in self._born:
            metrics = [(m.name, m.kind, readings[m.name]) for m in device.metrics]
            if self._send(session, self._topic("DBIRTH", device.id),
                          sparkplug.device_payload(self.seq, health, metrics), len(metrics)):
                self._born.add(device.id)
                self._published[device.id] = readings
                self._health[device.id] = health
            return
        last = self._published[device.id]
        changed = [(m.name, m.kind, readings[m.name]) for m in device.metrics
                   if moved(last.get(m.name), readings[m.name], m.scenario.deadband)]
        new_health = health if health != self._health.get(device.id) else None
        if not changed and new_health is None:
            return
        if self._send(session, self._topic("DDATA", device.id),
                      sparkplug.device_payload(self.seq, new_health, changed),
                      len(changed)):
            last.update({name: reading for name, _, reading in changed})
            self._health[device.id] = health

    def _send(self, session: Session, topic: str, payload_of_seq: bytes, values: int) -> bool:
        """Publish a node message with the current seq; on success the seq moves on (mod
        256).  A publish the slow broker cannot take is dropped and counted: the changes stay
        unpublished, so the next message carries the latest."""
        if not session.publish(topic, payload_of_seq):
            self.counters.dropped += max(values, 1)
            return False
        self.counters.sent += 1
        self.seq = (self.seq + 1) % 256
        return True

    # --- commands ---

    def message(self, topic: str, payload: bytes) -> list[Write]:
        """A message on a subscribed topic: the writes it asks for (a DCMD's)."""
        if self.cfg.primary_host is not None and \
                topic == sparkplug.state_topic(self.cfg.primary_host):
            online = sparkplug.host_online(payload)
            if online is not None:
                # Sparkplug 3.0 §5.9: a primary host offline ends the session (NDEATH,
                # DISCONNECT); the next one waits for it to be online again
                self.leave = self._born_node and not online
                self.host_online = online
            return []
        try:
            values = sparkplug.command_values(payload)
        except ValueError as err:
            log.warning("mqtt: %s: %s", topic, err)
            return []
        if topic == self._topic("NCMD"):
            if any(name == sparkplug.REBIRTH and value is True for name, value in values):
                log.info("mqtt: rebirth asked (NCMD)")
                self.rebirth()
            return []
        device = topic.rsplit("/", 1)[1]
        return [(device, name, value) for name, value in values]

    def _topic(self, kind: str, device: str | None = None) -> str:
        return sparkplug.topic(self.group, kind, self.node, device)
