"""The JSON profile: retained `GROUP/NODE/DEVICE/METRIC` topics with {"value", "timestamp",
"quality"} (UTC ms; good, stale or bad), published on change; writes on `.../set` (a bare
JSON value or {"value": V}); the Will `GROUP/NODE/status` = offline, retained, which Home
Assistant's discovery (one retained config per metric, republished when
`homeassistant/status` says online) takes as the availability topic."""
import json
import logging

from mbgw.config.mqtt import MqttConfig
from mbgw.northbound.catalogue import HEALTH, Device, Metric
from mbgw.northbound.connection import Session
from mbgw.northbound.counters import NorthboundCounters
from mbgw.northbound.sampler import Reading, Sampler, moved
from mbgw.northbound.sparkplug import now_ms

log = logging.getLogger("mbgw.northbound")

ONLINE, OFFLINE = "online", "offline"
DISCOVERY = "homeassistant"
HA_STATUS = f"{DISCOVERY}/status"
DOWN = "down"
Write = tuple[str, str, object]


class JsonNode:
    def __init__(self, cfg: MqttConfig, node: str, devices: dict[str, Device],
                 sampler: Sampler, counters: NorthboundCounters) -> None:
        self.cfg = cfg
        self.base = f"{cfg.group}/{node}"
        self.node = node
        self.devices = devices
        self.sampler = sampler
        self.counters = counters
        self._published: dict[str, Reading | str] = {}
        self._discover = True
        self.leave = False             # the JSON profile never ends a session itself

    def will(self, session: Session) -> None:
        session.will(self.status_topic, OFFLINE, 1, True)

    @property
    def status_topic(self) -> str:
        return f"{self.base}/status"

    def subscriptions(self) -> list[tuple[str, int]]:
        return [(f"{self.base}/+/+/set", 1), (f"{self.base}/+/+/+/set", 1), (HA_STATUS, 1)]

    def connected(self, session: Session) -> None:
        """A new session: every retained topic again (the broker may be a new one)."""
        self._published.clear()
        self._discover = True
        self._send(session, self.status_topic, ONLINE, qos=1)

    def farewell(self, session: Session) -> None:
        self._send(session, self.status_topic, OFFLINE, qos=1)

    def tick(self, session: Session, lines: dict[str, str]) -> None:
        self.sampler.begin()
        if self._discover:
            self._discover = not self._discovery(session)
        published = self.counters.lines
        for name, state in lines.items():
            if self._text(session, f"Lines/{name}/State", state):
                published[name] = state
        if len(published) > len(lines):            # a line a reload took away
            self.counters.lines = {n: s for n, s in published.items() if n in lines}
        for device in self.devices.values():
            health = self.sampler.health(device)
            self._text(session, f"{device.id}/{HEALTH}", health)
            readings = self.sampler.readings(device)
            for metric in device.metrics:
                self._value(session, device.id, metric, readings[metric.name], health)

    def _text(self, session: Session, path: str, text: str) -> bool:
        """text published at path unless it is there already: whether it was, now."""
        if self._published.get(path) == text:
            return False
        body = json.dumps({"value": text, "timestamp": now_ms(), "quality": "good"})
        if not self._send(session, f"{self.base}/{path}", body):
            return False
        self._published[path] = text
        return True

    def _value(self, session: Session, device: str, metric: Metric, reading: Reading,
               health: str) -> None:
        path = f"{device}/{metric.name}"
        if health == DOWN:
            reading = Reading(reading.value, stale=True) if reading.value is not None \
                else reading
        last = self._published.get(path)
        if isinstance(last, Reading) and not moved(last, reading, metric.scenario.deadband):
            return
        quality = "bad" if health == DOWN else "stale" if reading.stale else \
            "good" if reading.value is not None else "bad"
        value = None if quality == "stale" else reading.value
        body = json.dumps({"value": value, "timestamp": now_ms(), "quality": quality})
        if self._send(session, f"{self.base}/{path}", body):
            self._published[path] = reading

    def _discovery(self, session: Session) -> bool:
        for device in self.devices.values():
            for metric in device.metrics:
                topic, config = self.discovery(device, metric)
                if not self._send(session, topic, json.dumps(config)):
                    return False
        return True

    def discovery(self, device: Device, metric: Metric) -> tuple[str, dict]:
        """Home Assistant MQTT discovery: the topic and config of one metric."""
        writable = self.cfg.role is not None and metric.kind not in ("string", "bool")
        component = "binary_sensor" if metric.kind == "bool" else \
            "number" if writable else "sensor"
        object_id = f"{device.id}_{metric.name}".replace("/", "_")
        state = f"{self.base}/{device.id}/{metric.name}"
        config: dict = {
            "name": metric.name, "unique_id": f"mbgw_{self.node}_{object_id}",
            "state_topic": state, "value_template": "{{ value_json.value }}",
            "availability_topic": self.status_topic, "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
            "device": {"identifiers": [f"mbgw_{self.node}_{device.id}"],
                       "name": f"{self.node} {device.id}", "manufacturer": "mbgw",
                       "via_device": f"mbgw_{self.node}"}}
        if component == "binary_sensor":
            config.update(payload_on="True", payload_off="False")
        if component == "number":
            config["command_topic"] = f"{state}/set"
        return f"{DISCOVERY}/{component}/{self.node}/{object_id}/config", config

    def _send(self, session: Session, topic: str, body: str, qos: int = 0) -> bool:
        if not session.publish(topic, body, qos=qos, retain=True):
            self.counters.dropped += 1
            return False
        self.counters.sent += 1
        return True

    def message(self, topic: str, payload: bytes) -> list[Write]:
        if topic == HA_STATUS:
            if payload.strip() == ONLINE.encode():
                self._discover = True
            return []
        path = topic[len(self.base) + 1:].removesuffix("/set")
        device, _, name = path.partition("/")
        try:
            value = json.loads(payload)
        except ValueError:
            log.warning("mqtt: %s: not JSON", topic)
            return []
        if isinstance(value, dict):
            value = value.get("value")
        return [(device, name, value)]
