"""[mqtt] in a daemon of any mode: northbound MQTT started with the scenarios, started again
by a reload that changes [mqtt], the scenarios or the firewall, stopped with the daemon; its
figures in the status and on /metrics."""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from mbgw.firewall.guard import Firewall

if TYPE_CHECKING:
    from mbgw.northbound.runner import Northbound

log = logging.getLogger("mbgw")


class NorthboundService:
    def __init__(self, parts, engines: dict) -> None:
        self.parts = parts
        self.engines = engines
        self.running: Northbound | None = None
        self._settings: tuple = ()

    def start(self, cfg) -> None:
        self._settings = _settings(cfg)
        if not cfg.mqtt.enabled:
            return
        # paho-mqtt and protobuf are loaded by the first [mqtt] only: a daemon without MQTT
        # starts without them
        from mbgw.northbound.runner import Northbound
        self.running = Northbound(cfg.mqtt, cfg.scenarios, self.parts.table, self.engines,
                                  self._lines, Firewall(cfg.firewall),
                                  getattr(cfg, "upstream_tls", None))
        self.running.start()

    async def reconfigure(self, new) -> None:
        if _settings(new) == self._settings:
            return
        await self.stop()
        self.start(new)

    async def stop(self) -> None:
        if self.running is not None:
            await self.running.stop()
            self.running = None

    def status(self) -> dict | None:
        return self.running.status() if self.running is not None else None

    def with_status(self, commands: dict) -> dict:
        """The control commands, with "mqtt" in the status while MQTT is on."""
        mode_status = commands["status"]

        def status(request: dict) -> dict:
            out = mode_status(request)
            mqtt = self.status()
            if mqtt is not None and isinstance(out, dict):
                out = {**out, "mqtt": mqtt}
            return out
        return {**commands, "status": status}

    def with_metrics(self, collector):
        collector.mqtt = self.status
        return collector

    def _lines(self) -> dict[str, str]:
        return {row["name"]: str(row.get("state", "")) for row in self.parts.lines()} or \
            {"serial": "up"}


def _settings(cfg) -> tuple:
    return cfg.mqtt, cfg.scenarios, cfg.firewall, getattr(cfg, "upstream_tls", None)
