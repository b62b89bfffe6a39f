"""Writes from MQTT (Sparkplug DCMD, JSON .../set): to a read scenario's device at its
address, encoded with its type, as a firewall request of a client with role `[mqtt] role` on
listener `mqtt` (the unit: the serial address).  Without a role every write is refused; a
refusal is counted and logged."""
import asyncio
import dataclasses
import logging

from mbgw.firewall.guard import Firewall
from mbgw.net.ratelimit import RateLimitedLog
from mbgw.northbound import codec
from mbgw.northbound.catalogue import Device
from mbgw.northbound.counters import NorthboundCounters

log = logging.getLogger("mbgw.northbound")

LISTENER = "mqtt"
ANY_HOST = "0.0.0.0"               # MQTT writes have no client address of their own
WRITE_WAIT_S = 10.0


class Writes:
    def __init__(self, role: str | None, firewall: Firewall, devices: dict[str, Device],
                 engines: dict, counters: NorthboundCounters) -> None:
        self.role = role
        self.firewall = firewall
        self.devices = devices
        self.engines = engines
        self.counters = counters
        self._refusals = RateLimitedLog()

    async def write(self, device_id: str, name: str, value: object) -> bool:
        """Send one write; False when it is refused or fails (logged)."""
        device = self.devices.get(device_id)
        metric = None if device is None else \
            next((m for m in device.metrics if m.name == name), None)
        if device is None or metric is None:
            return self._refuse(f"{device_id}/{name}: no such metric")
        sc = metric.scenario
        try:
            pdu = codec.encode(sc, name, value)
        except codec.WriteRefused as err:
            return self._refuse(f"{device_id}/{name}: {err}")
        unit = sc.slave if sc.slave is not None else sc.unit
        if self.role is None:
            return self._refuse(f"{device_id}/{name}: no [mqtt] role: writes are refused")
        guard = self.firewall.guard(ANY_HOST, self.role, LISTENER)
        if guard is not None and not guard.allows(unit, pdu):
            self.firewall.refused(guard, LISTENER, self.role, unit, pdu)
            return self._refuse(f"{device_id}/{name}: refused by the firewall (role "
                                f"{self.role})")
        engine = self.engines.get(sc.kind)
        if engine is None:
            return self._refuse(f"{device_id}/{name}: the {sc.kind} scenarios do not run")
        # the scenario's target with the write's function, so its reply is checked as one
        write = dataclasses.replace(sc, function=pdu[0])
        result = await asyncio.to_thread(engine.request_test, write, WRITE_WAIT_S, pdu)
        if not result.get("ok"):
            log.warning("mqtt: write %s/%s = %r: %s", device_id, name, value,
                        result.get("message") or result.get("error"))
            return False
        self.counters.writes += 1
        log.info("mqtt: wrote %s/%s = %r", device_id, name, value)
        return True

    def _refuse(self, why: str) -> bool:
        self.counters.refused += 1
        left_out = self._refusals.due(why.split(":", 1)[0])
        if left_out is not None:
            log.warning("mqtt: write refused: %s%s", why,
                        f" ({left_out} more since the last report)" if left_out else "")
        return False
