"""The `[[monitor]]` maps: what a listen-only line (`mode = "monitor"`) stores in the
exchange table.  Each map takes one unit's answered reads of one function (3 and 4:
registers; 1 and 2: one bit per register, 0 or 1) over an address range to the table's
registers from `table`."""
import itertools
from dataclasses import dataclass
from functools import partial

from mbgw.config.tables import check_keys, parse_each, typed
from mbgw.errors import ConfigError

MONITOR_TABLE = "monitor"
MONITOR_MODE = "monitor"        # a [[line]]'s mode: mbgw only listens
MONITOR_KEYS = ("line", "unit", "function", "address", "quantity", "table")
FUNCTIONS = (1, 2, 3, 4)        # the reads: coils, discrete inputs, holding, input registers
UNITS = (1, 247)                # a serial address (a broadcast is never answered)
ADDRESSES = 0x10000
TABLE_END = 0x8000              # the configuration zone begins here (mbgw.table.memory)


@dataclass(frozen=True)
class MonitorMap:
    index: int                  # its place among the [[monitor]] tables, from 1
    line: str
    unit: int
    function: int
    address: int
    quantity: int
    table: int

    @property
    def label(self) -> str:
        return f"monitor {self.index}"

    @property
    def bits(self) -> bool:
        return self.function in (1, 2)


def parse_monitors(found: list[dict]) -> tuple[tuple[MonitorMap, ...], list[str]]:
    return parse_each(found, _parse_map)


def _parse_map(index: int, fields: dict) -> MonitorMap:
    label = f"monitor {index}"
    check_keys(label, fields, MONITOR_KEYS)
    key = partial(typed, label, fields)
    for name in MONITOR_KEYS:
        if name not in fields:
            raise ConfigError(f"{label}.{name}: missing; a map has {', '.join(MONITOR_KEYS)}")
    line = key("line", str, "a line name")
    unit = _number(label, key, "unit", *UNITS)
    function = _number(label, key, "function", FUNCTIONS[0], FUNCTIONS[-1])
    address = _number(label, key, "address", 0, ADDRESSES - 1)
    quantity = _number(label, key, "quantity", 1, ADDRESSES - address)
    table = _number(label, key, "table", 0, TABLE_END - 1)
    if table + quantity > TABLE_END:
        raise ConfigError(f"{label}.quantity: {quantity} registers from table {table} go "
                          f"beyond the table's {TABLE_END} (the configuration zone follows)")
    return MonitorMap(index, line, unit, function, address, quantity, table)


def _number(label: str, key, name: str, low: int, high: int) -> int:
    value = key(name, int, "an integer")
    if not low <= value <= high:
        raise ConfigError(f"{label}.{name}: {value} out of range {low}..{high}")
    return value


def monitor_problems(maps: tuple[MonitorMap, ...], line_modes: dict[str, str]) -> list[str]:
    """What check-config refuses across maps: a line that is not there or not in monitor
    mode (line_modes: every line's mode by name), table ranges that overlap."""
    problems = []
    for m in maps:
        mode = line_modes.get(m.line)
        if mode is None:
            problems.append(f"{m.label}.line {m.line!r}: no such line")
        elif mode != MONITOR_MODE:
            problems.append(f"{m.label}.line {m.line!r}: the line is in {mode} mode; a map "
                            f"reads a line in monitor mode")
    ordered = sorted(maps, key=lambda m: m.table)
    for before, after in itertools.pairwise(ordered):
        end = min(after.table + after.quantity, before.table + before.quantity)
        if after.table < end:
            problems.append(f"{after.label}.table: registers {after.table}..{end - 1} are "
                            f"{before.label}'s already")
    return problems


def monitor_settings(cfg) -> tuple:
    """What the monitor lines run with: their lines and the maps (a daemon's cfg); a reload
    that changes this reconfigures them (monitor.lines.MonitorLines.reconfigure)."""
    return tuple(line for line in cfg.lines if line.is_monitor), cfg.monitors


def map_fields(m: MonitorMap) -> dict:
    """A map as the keys of its [[monitor]] table (what parse_monitors reads)."""
    return {"line": m.line, "unit": m.unit, "function": m.function, "address": m.address,
            "quantity": m.quantity, "table": m.table}
