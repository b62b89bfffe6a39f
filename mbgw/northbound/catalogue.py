"""What is published: one device per serial address (or server and unit) that a read
scenario polls, each with its scenarios' metrics and its Health, built once per
configuration."""
from dataclasses import dataclass, field

from mbgw.config.scenario import ScenarioConfig
from mbgw.northbound import codec
from mbgw.northbound.names import device_id

HEALTH = "Health"


@dataclass(frozen=True)
class Metric:
    name: str
    scenario: ScenarioConfig
    kind: str                      # codec.value_type: uint16, ..., bool, string
    index: int                     # which of the scenario's values


@dataclass
class Device:
    id: str
    scenarios: list[ScenarioConfig] = field(default_factory=list)
    metrics: list[Metric] = field(default_factory=list)

    @property
    def first(self) -> ScenarioConfig:
        """The scenario whose target's health is the device's."""
        return self.scenarios[0]


def devices(scenarios) -> dict[str, Device]:
    """The devices of the enabled read scenarios, by id, in the configuration's order."""
    found: dict[str, Device] = {}
    for sc in scenarios:
        if not sc.reads or not sc.enabled or sc.broadcast:
            continue
        device = found.setdefault(device_id(sc), Device(device_id(sc)))
        device.scenarios.append(sc)
        kind = codec.value_type(sc)
        device.metrics += [Metric(name, sc, kind, i)
                           for i, name in enumerate(codec.element_names(sc))]
    return found
