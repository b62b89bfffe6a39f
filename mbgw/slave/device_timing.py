"""A slave-mode line's timing by serial address: the line's own, but for the units its
[[device]] tables give their own stout, retries, pause, down-after and probe-interval.

Built once per configuration (at start and on each reload) as 256-entry lists, so that the
transaction reads an address's timing with one index and allocates nothing."""
from mbgw.config.lines import DeviceConfig
from mbgw.config.model import Demotion, SlaveConfig

NS_PER_MS = 1_000_000


class DeviceTiming:
    def __init__(self, stout_ms: int, retries: int = 0, late_window_ms: int = 0,
                 own: tuple[DeviceConfig, ...] = (), late_window_is_stout: bool = False
                 ) -> None:
        """late_window_is_stout: the late window follows stout (late-window unset), so a
        device's own stout is its late window too."""
        self.own = own
        self.stout_ns = [stout_ms * NS_PER_MS] * 256
        self.retries = [retries] * 256
        self.pause_us = [0] * 256
        self.late_window_ns = [late_window_ms * NS_PER_MS] * 256
        self.flags = bytearray(256)     # 1: the address has timing of its own (read by C)
        for device in own:
            unit = device.unit
            self.flags[unit] = 1
            if device.stout_ms is not None:
                self.stout_ns[unit] = device.stout_ms * NS_PER_MS
                if late_window_is_stout:
                    self.late_window_ns[unit] = device.stout_ms * NS_PER_MS
            if device.retries is not None:
                self.retries[unit] = device.retries
            self.pause_us[unit] = device.pause_ms * 1000

    @classmethod
    def of_line(cls, cfg: SlaveConfig, line: str) -> "DeviceTiming":
        """The timing of line `line` of cfg (its [[device]] tables among cfg.devices)."""
        own = tuple(d for d in cfg.devices if d.line == line)
        return cls(cfg.serial.stout_ms, cfg.retries, cfg.late_window, own,
                   cfg.late_window_ms is None)

    @property
    def longest_stout_ms(self) -> int:
        return max(self.stout_ns) // NS_PER_MS

    @property
    def most_retries(self) -> int:
        return max(self.retries)

    @property
    def longest_pause_ms(self) -> float:
        return max(self.pause_us) / 1000

    def demotions(self, line: Demotion) -> dict[int, tuple[Demotion, dict]]:
        """By address with timing of its own: its demotion and its timing in full, as status
        shows it (DeviceHealth.set_rule's `own`)."""
        own = {}
        for device in self.own:
            unit, demotion = device.unit, device.demotion(line)
            own[unit] = (demotion, {
                "stout_ms": self.stout_ns[unit] // NS_PER_MS, "retries": self.retries[unit],
                "pause_ms": self.pause_us[unit] // 1000, "down_after": demotion.down_after,
                "probe_interval_ms": demotion.probe_interval_ms})
        return own
