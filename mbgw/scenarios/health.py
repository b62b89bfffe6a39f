"""Demotion for scenarios: the rule direct requests obey (mbgw.ops.device_stats), applied to
a scenario's runs.  While its device (a serial address) or its server (a TCP scenario's
host and port) is down, its runs are skipped, but for the probe the rule lets through
(`admit`).  A serial scenario shares the line's DeviceHealth, so a client's request and a
scenario's run are one device's probes; a TCP server's health is the TCP runner's, judged by
the same HealthRule (down-after, probe-interval)."""
import time

from mbgw.config.scenario import ScenarioConfig
from mbgw.config.server_address import split_server
from mbgw.ops.device_stats import DOWN, UP, DeviceHealth, DeviceStats, HealthRule
from mbgw.scenarios.exchange import DEVICE_DOWN, SERVER_DOWN


class SerialHealth:
    """The serial scenarios' view of the line's devices (on the line thread)."""
    down_kind = DEVICE_DOWN

    def __init__(self, devices: DeviceHealth) -> None:
        self.devices = devices

    def down(self, sc: ScenarioConfig) -> bool:
        return sc.slave is not None and self.devices.rule.down[sc.slave] == 1

    def state(self, sc: ScenarioConfig) -> str:
        """up, degraded or down, for any thread: nothing is created here."""
        stats = self.devices.find(sc.slave) if sc.slave is not None else None
        return UP if stats is None else stats.health

    def admit(self, sc: ScenarioConfig, now: float) -> bool:
        """Whether a run of sc goes on the line at now: the probe of a device that is down
        (DeviceStats.admit, which also counts a refusal as demoted_rejects)."""
        return sc.slave is None or self.devices.get(sc.slave).admit(now)

    def next_probe_in(self, sc: ScenarioConfig) -> float | None:
        """For the status (any thread): a device that is down exists already, so nothing is
        created here."""
        if not self.down(sc):
            return None
        assert sc.slave is not None
        return _probe_in(self.devices.get(sc.slave))


class ServerHealth:
    """The TCP scenarios' servers (on the TCP runner's thread): one DeviceStats per host and
    port, judged by `rule`; the runner books each dial's outcome (answered, failed)."""
    down_kind = SERVER_DOWN

    def __init__(self, rule: HealthRule | None = None) -> None:
        self.rule = rule if rule is not None else HealthRule()
        self._servers: dict[tuple[str, int], DeviceStats] = {}

    def of(self, host: str, port: int) -> DeviceStats:
        stats = self._servers.get((host, port))
        if stats is None:
            name = f"scenario server [{host}]:{port}" if ":" in host else \
                f"scenario server {host}:{port}"
            stats = self._servers[(host, port)] = DeviceStats(None, rule=self.rule, name=name)
        return stats

    def _of(self, sc: ScenarioConfig) -> DeviceStats:
        assert sc.server is not None
        return self.of(*split_server(sc.server))

    def down(self, sc: ScenarioConfig) -> bool:
        return self._of(sc).health == DOWN

    def state(self, sc: ScenarioConfig) -> str:
        """up, degraded or down, for any thread: nothing is created here."""
        stats = self._servers.get(split_server(sc.server or ""))
        return UP if stats is None else stats.health

    def admit(self, sc: ScenarioConfig, now: float) -> bool:
        return self._of(sc).admit(now)

    def next_probe_in(self, sc: ScenarioConfig) -> float | None:
        assert sc.server is not None
        stats = self._servers.get(split_server(sc.server))
        return None if stats is None or stats.health != DOWN else _probe_in(stats)

    def rejudge(self, now: float) -> None:
        """New settings (a reload): every server judged again by them."""
        for stats in self._servers.values():
            stats.rejudge()
            stats.reprobe(now)


def _probe_in(stats: DeviceStats) -> float:
    return max(0.0, stats.probe_at - time.monotonic())
