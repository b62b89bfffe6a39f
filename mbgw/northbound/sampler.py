"""The published state read on the loop: each metric's value from the exchange table (None
before its scenario's first read), whether it is stale, and each device's health.  Read
only: a line thread waits for it at most while an engine's lock hands over its data ages,
once a tick."""
from dataclasses import dataclass

from mbgw.config.scenario import ScenarioConfig
from mbgw.northbound import codec
from mbgw.northbound.catalogue import Device

UP = "up"


@dataclass(frozen=True)
class Reading:
    value: codec.Value | None      # None: not read yet, or stale
    stale: bool = False


class Sampler:
    """Reads a device's metrics and health from the table and the scenarios' engines (by
    kind: "serial", "tcp")."""

    def __init__(self, table, engines: dict, stale_after_ms: int) -> None:
        self.table = table
        self.engines = engines
        self.stale_after_ms = stale_after_ms
        self._ages: dict[str, dict[str, float | None]] = {}

    def begin(self) -> None:
        """A new tick: each engine's data ages read once (one hold of its lock, which the
        runner's thread also takes), for every device the tick reads."""
        self._ages = {kind: engine.data_ages() for kind, engine in self.engines.items()
                      if engine is not None}

    def health(self, device: Device) -> str:
        engine = self.engines.get(device.first.kind)
        health = getattr(engine, "health", None)
        return UP if health is None else health.state(device.first)

    def readings(self, device: Device) -> dict[str, Reading]:
        out: dict[str, Reading] = {}
        for sc in device.scenarios:
            out.update(self._scenario(sc))
        return out

    def _scenario(self, sc: ScenarioConfig) -> dict[str, Reading]:
        names = codec.element_names(sc)
        age = self._ages.get(sc.kind, {}).get(sc.name)
        if age is None:
            return dict.fromkeys(names, Reading(None))
        stale_after = sc.stale_after_ms or self.stale_after_ms
        if stale_after and age * 1000 > stale_after:
            return dict.fromkeys(names, Reading(None, stale=True))
        words = self.table.read_bits(sc.table, sc.quantity) if sc.bits else \
            self.table.read(sc.table, sc.quantity)
        return {name: Reading(value) for name, value in zip(names, codec.decode(sc, words),
                                                             strict=True)}


def moved(old: Reading | None, new: Reading, deadband: float) -> bool:
    """Whether new is worth publishing after old (report by exception, with a deadband for
    numbers)."""
    if old is None or old.stale != new.stale or (old.value is None) != (new.value is None):
        return True
    if old.value == new.value:
        return False
    if deadband and isinstance(new.value, (int, float)) and not isinstance(new.value, bool) \
            and isinstance(old.value, (int, float)):
        return abs(new.value - old.value) > deadband
    return True
