"""A scenario (VPGate §3.5, §3.6.3, §6.2-6.3): one request the gateway sends on its own, to a
serial slave or a Modbus TCP server, cyclically or when the table data it writes changes; a
read stores what it read in the exchange table, a write sends table data.  Each is a
`[[scenario]]` table of the configuration file; `parse_scenario` checks one (every error names
the scenario and the key)."""
import re
from dataclasses import dataclass

from mbgw.config.server_address import (
    DEFAULT_SERVER_PORT,
    DEFAULT_TLS_SERVER_PORT,
    parse_server,
    split_server,
)
from mbgw.config.slaveid import parse_fingerprint
from mbgw.errors import ConfigError

NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")
READS = (1, 2, 3, 4, 23)
WRITES = (5, 6, 15, 16, 23)
BIT_FUNCTIONS = (1, 2, 5, 15)
FUNCTIONS = (1, 2, 3, 4, 5, 6, 15, 16, 23)
FUNCTION_NAMES = {1: "read coils", 2: "read discrete inputs", 3: "read holding registers",
                  4: "read input registers", 5: "write single coil", 6: "write single register",
                  15: "write multiple coils", 16: "write multiple registers",
                  23: "read/write multiple registers"}
# the Modbus limits of a quantity (Modbus Application Protocol V1.1b3, section 6)
QUANTITY_RANGES = {1: (1, 2000), 2: (1, 2000), 3: (1, 125), 4: (1, 125), 5: (1, 1), 6: (1, 1),
                   15: (1, 1968), 16: (1, 123), 23: (1, 125)}
WRITE_QUANTITY_RANGE_23 = (1, 121)
MAX_PER_KIND = 100                 # VPGate: 100 serial scenarios, 100 TCP scenarios
CYCLE_RANGE = (100, 65535)         # ms
RETRIES_RANGE = (0, 65535)       # as VPGate allows
DEFAULT_RETRIES = 2                # VPGate's default for scenarios
STALE_AFTER_RANGE = (0, 3_600_000)  # ms; 0: off
SLAVE_RANGE = (0, 247)             # 0: broadcast, writes only
UNIT_RANGE = (0, 255)
TRIGGER_CHANGE = "change"
REGISTERS = 0x10000
BITS = 0x10000                     # table bit B: bit B % 16 of register B // 16
CONFIG_ZONE_FIRST = 0x8000         # read-only: a read scenario cannot store there
KEYS = ("name", "slave", "server", "unit", "function", "address", "quantity", "table",
        "read-address", "read-quantity", "read-table", "write-address", "write-quantity",
        "write-table", "cycle", "trigger", "retries", "stale-after", "enabled", "tls",
        "fingerprint", "send-unwritten", "type", "swap", "deadband")
# what a read scenario's data is, published northbound (MQTT): the registers each type takes
# (None: any number; string: two characters a register)
TYPE_REGISTERS = {"uint16": 1, "int16": 1, "uint32": 2, "int32": 2, "float32": 2, "bool": 1,
                  "string": None}
SWAPS = ("none", "bytes", "words")     # bytes: BADC, words: CDAB


@dataclass(frozen=True)
class ScenarioConfig:
    name: str
    function: int
    address: int                   # in the device (FC 23: the read part)
    quantity: int
    table: int                     # first table register; bit functions: a table bit address
    slave: int | None = None       # serial scenario
    server: str | None = None      # TCP scenario: "host:port"
    unit: int = 1                  # TCP scenario
    cycle_ms: int | None = None
    on_change: bool = False
    write_address: int | None = None   # FC 23's write part
    write_quantity: int | None = None
    write_table: int | None = None
    retries: int = DEFAULT_RETRIES
    stale_after_ms: int = 0
    enabled: bool = True
    tls: bool = False              # TCP scenario: over Modbus/TCP Security
    fingerprint: bytes | None = None   # tls: the server certificate's SHA-256, pinned
    send_unwritten: bool = False   # a write: send table registers nobody has written yet
    value_type: str | None = None  # a read's data as one typed value (None: uint16 registers
    swap: str = "none"             # or bits, one value each); swap: the byte/word order
    deadband: float = 0.0          # a published number changes by more than this, or not

    @property
    def kind(self) -> str:
        return "serial" if self.slave is not None else "tcp"

    @property
    def reads(self) -> bool:
        return self.function in READS

    @property
    def writes(self) -> bool:
        return self.function in WRITES

    @property
    def bits(self) -> bool:
        return self.function in BIT_FUNCTIONS

    @property
    def broadcast(self) -> bool:
        return self.slave == 0

    @property
    def target(self) -> str:
        """Where it goes, for status: "slave 45" or "host:502 unit 1"."""
        return f"slave {self.slave}" if self.slave is not None else \
            f"{self.server} unit {self.unit}{' TLS' if self.tls else ''}"

    def table_ranges(self) -> list[tuple[int, int, str]]:
        """(first register, count, "read" | "write"): the table registers it stores into
        (read) and sends from (write)."""
        if self.function == 23:
            return [(self.table, self.quantity, "read"),
                    (self.write_table or 0, self.write_quantity or 0, "write")]
        direction = "read" if self.reads else "write"
        if self.bits:
            first = self.table // 16
            return [(first, (self.table + self.quantity - 1) // 16 - first + 1, direction)]
        return [(self.table, self.quantity, direction)]

    def write_range(self) -> tuple[int, int] | None:
        """The table registers a change scenario watches (what it sends), or None."""
        for first, count, direction in self.table_ranges():
            if direction == "write":
                return first, count
        return None

    def read_range(self) -> tuple[int, int] | None:
        for first, count, direction in self.table_ranges():
            if direction == "read":
                return first, count
        return None

    def fields(self) -> dict:
        """The scenario as the keys of its `[[scenario]]` table (what parse_scenario reads)."""
        out: dict = {"name": self.name}
        if self.slave is not None:
            out["slave"] = self.slave
        else:
            out["server"] = self.server
            out["unit"] = self.unit
            if self.tls:
                out["tls"] = True
            if self.fingerprint:
                out["fingerprint"] = self.fingerprint.hex(":").upper()
        out["function"] = self.function
        prefix = "read-" if self.function == 23 else ""
        out[f"{prefix}address"] = bit_text(self.address) if self.bits else self.address
        out[f"{prefix}quantity"] = self.quantity
        out[f"{prefix}table"] = bit_text(self.table) if self.bits else self.table
        if self.function == 23:
            out.update({"write-address": self.write_address,
                        "write-quantity": self.write_quantity, "write-table": self.write_table})
        if self.on_change:
            out["trigger"] = TRIGGER_CHANGE
        else:
            out["cycle"] = self.cycle_ms
        if self.retries != DEFAULT_RETRIES:
            out["retries"] = self.retries
        if self.stale_after_ms:
            out["stale-after"] = self.stale_after_ms
        if not self.enabled:
            out["enabled"] = False
        if self.send_unwritten:
            out["send-unwritten"] = True
        if self.value_type is not None:
            out["type"] = self.value_type
        if self.swap != "none":
            out["swap"] = self.swap
        if self.deadband:
            out["deadband"] = self.deadband
        return out


def bit_text(bit: int) -> str:
    """A bit address as VPGate writes it: "R.B" (register R, bit B)."""
    return f"{bit // 16}.{bit % 16}"


class _Fields:
    """The keys of one [[scenario]], read once each, with errors naming it."""

    def __init__(self, fields: dict, label: str) -> None:
        self.fields = fields
        self.label = label

    def error(self, key: str, value, why: str) -> ConfigError:
        shown = f" {value!r}" if isinstance(value, str) else f" {value}"
        return ConfigError(f"{self.label}: {key}{shown}: {why}")

    def has(self, key: str) -> bool:
        return key in self.fields

    def integer(self, key: str, low: int, high: int, default=None, bits: bool = False):
        if key not in self.fields:
            if default is None:
                raise ConfigError(f"{self.label}: {key}: missing")
            return default
        value = self.fields[key]
        number = _number(value, bits)
        if number is None:
            raise self.error(key, value, "expected a number" +
                             (' or a bit address "R.B" (register R, bit B 0-15)' if bits
                              else ""))
        if not low <= number <= high:
            if bits and isinstance(value, str) and "." in value:
                raise self.error(key, value, f"out of range 0.0..{bit_text(high)}")
            raise self.error(key, value, f"out of range {low}..{high}")
        return number

    def boolean(self, key: str, default: bool) -> bool:
        value = self.fields.get(key, default)
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "on", "yes", "1",
                                                         "false", "off", "no", "0"):
            return value.lower() in ("true", "on", "yes", "1")
        raise self.error(key, value, "expected true or false")


def _number(value, bits: bool) -> int | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if not isinstance(value, str):
        return None
    text = value.strip()
    if bits:
        match = re.fullmatch(r"(\d+)\.(\d+)", text)
        if match:
            register, bit = int(match[1]), int(match[2])
            return register * 16 + bit if bit < 16 else None
    try:
        return int(text, 0)
    except ValueError:
        return None


class ScenarioError(ConfigError):
    """Every problem of one scenario, each naming it and the key; str(): one a line."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


def parse_scenario(fields: dict, where: str, label: str | None = None) -> ScenarioConfig:
    """One `[[scenario]]` table (TOML values, or the strings of KEY=VALUE words) as a
    ScenarioConfig.  `where` names it in errors until its name is known (e.g. "scenario 3");
    label: how errors name it, "scenario NAME" by default.  Raises ScenarioError with every
    problem found, each naming the scenario and the key."""
    name = fields.get("name")
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        why = "missing" if name is None else \
            f"{name!r}: expected 1 to 64 letters, digits, - or _"
        raise ScenarioError([f"{where}: name: {why}"])
    f = _Fields(fields, label or f"scenario {name}")
    problems = [f"{f.label}: {k}: unknown key{_close_key(k)}" for k in fields if k not in KEYS]

    def checked(check, default=None):
        try:
            return check()
        except ConfigError as err:
            problems.append(str(err))
            return default

    function = checked(lambda: _function(f))
    target = checked(lambda: _target(f, 6 if function is None else function))
    retries = checked(lambda: f.integer("retries", *RETRIES_RANGE, default=DEFAULT_RETRIES))
    enabled = checked(lambda: f.boolean("enabled", True))
    if function is None:
        checked(lambda: _trigger(f, 6))
        raise ScenarioError(problems)
    read = checked(lambda: _read_or_only_part(f, function))
    write = checked(lambda: _write_part(f)) if function == 23 else (None, None, None)
    trigger = checked(lambda: _trigger(f, function))
    stale_after = checked(lambda: _stale_after(f, function))
    send_unwritten = checked(lambda: _send_unwritten(f, function))
    fingerprint = checked(lambda: _fingerprint(f, target[3])) if target else None
    untyped = (None, "none", 0.0)
    typed = checked(lambda: _typed(f, function, read[1]), untyped) if read else untyped
    if problems:
        raise ScenarioError(problems)
    slave, server, unit, tls = target
    address, quantity, table = read
    cycle_ms, on_change = trigger
    return ScenarioConfig(
        name=name, function=function, address=address, quantity=quantity, table=table,
        slave=slave, server=server, unit=unit, cycle_ms=cycle_ms, on_change=on_change,
        write_address=write[0], write_quantity=write[1], write_table=write[2],
        retries=retries, stale_after_ms=stale_after, enabled=enabled, tls=tls,
        fingerprint=fingerprint, send_unwritten=send_unwritten, value_type=typed[0],
        swap=typed[1], deadband=typed[2])


def _close_key(key: str) -> str:
    """'; did you mean address?' for adress, else the list of keys."""
    import difflib
    close = difflib.get_close_matches(key, KEYS, n=1)
    return f"; did you mean {close[0]}?" if close else f" (keys: {', '.join(KEYS)})"


def _function(f: "_Fields") -> int:
    function = f.integer("function", 0, 255)
    if function not in FUNCTIONS:
        raise f.error("function", f.fields["function"],
                      f"expected one of {', '.join(map(str, FUNCTIONS))}")
    return function


def _stale_after(f: "_Fields", function: int) -> int:
    stale_after = f.integer("stale-after", *STALE_AFTER_RANGE, default=0)
    if stale_after and function not in READS:
        raise f.error("stale-after", f.fields["stale-after"],
                      "only a read scenario's data can be stale")
    return stale_after


def _send_unwritten(f: "_Fields", function: int) -> bool:
    send_unwritten = f.boolean("send-unwritten", False)
    if send_unwritten and function not in WRITES:
        raise ConfigError(f"{f.label}: send-unwritten: only a write sends table data "
                          f"(function 5, 6, 15, 16 or 23)")
    return send_unwritten


def _typed(f: "_Fields", function: int, quantity: int) -> tuple[str | None, str, float]:
    """(type, swap, deadband): how a read's data is published northbound."""
    value_type = f.fields.get("type")
    swap = f.fields.get("swap", "none")
    deadband = f.fields.get("deadband", 0.0)
    for key in ("type", "swap", "deadband"):
        if f.has(key) and function not in READS:
            raise ConfigError(f"{f.label}: {key}: only a read scenario's data is published")
    if value_type is not None and value_type not in TYPE_REGISTERS:
        raise f.error("type", value_type, f"expected one of {', '.join(TYPE_REGISTERS)}")
    if swap not in SWAPS:
        raise f.error("swap", swap, f"expected one of {', '.join(SWAPS)}")
    if isinstance(deadband, str):
        try:
            deadband = float(deadband)
        except ValueError:
            raise f.error("deadband", deadband, "expected a number") from None
    if isinstance(deadband, bool) or not isinstance(deadband, (int, float)) \
            or not 0 <= deadband < float("inf"):
        raise f.error("deadband", deadband, "expected a number, 0 or more")
    bits = function in BIT_FUNCTIONS
    if bits and value_type not in (None, "bool"):
        raise f.error("type", value_type, "a bit scenario's data is bool")
    if bits and swap != "none":
        raise f.error("swap", swap, "a bit scenario's data has no byte order")
    size = TYPE_REGISTERS.get(value_type or "")
    if size is not None and quantity != size:
        unit = "bit" if bits else "register" if size == 1 else "registers"
        key = "read-quantity" if function == 23 else "quantity"
        raise f.error("type", value_type, f"takes {size} {unit}, not {key} {quantity}")
    if value_type in ("bool", "string") and deadband:
        raise f.error("deadband", deadband, f"only for a number, not {value_type}")
    return value_type, swap, float(deadband)


def _fingerprint(f: "_Fields", tls: bool) -> bytes | None:
    if not f.has("fingerprint"):
        return None
    value = f.fields["fingerprint"]
    if not tls:
        raise ConfigError(f"{f.label}: fingerprint: only with tls = true")
    if not isinstance(value, str):
        raise f.error("fingerprint", value, "expected the server certificate's SHA-256 "
                                            "fingerprint in hex")
    return parse_fingerprint(f"{f.label}", value)


def _target(f: _Fields, function: int) -> tuple[int | None, str | None, int, bool]:
    if f.has("slave") == f.has("server"):
        raise ConfigError(f"{f.label}: give slave (a serial scenario) or server (a TCP "
                          f"scenario)" + (", not both" if f.has("slave") else ""))
    if f.has("slave"):
        if f.has("unit"):
            raise ConfigError(f"{f.label}: unit: only for a TCP scenario (server); a serial "
                              f"scenario's address is slave")
        if f.has("tls"):
            raise ConfigError(f"{f.label}: tls: only for a TCP scenario (server)")
        slave = f.integer("slave", *SLAVE_RANGE)
        if slave == 0 and function not in (5, 6, 15, 16):
            raise f.error("slave", 0, "the broadcast address takes writes only "
                                      "(function 5, 6, 15 or 16)")
        return slave, None, 1, False
    tls = f.boolean("tls", False)
    value = f.fields["server"]
    if not isinstance(value, str):
        raise f.error("server", value, "expected \"host:port\"")
    try:
        server = parse_server(value, DEFAULT_TLS_SERVER_PORT if tls else DEFAULT_SERVER_PORT)
    except ConfigError as err:
        raise ConfigError(f"{f.label}: server {err}") from None
    return None, server, f.integer("unit", *UNIT_RANGE, default=1), tls


def _read_or_only_part(f: _Fields, function: int) -> tuple[int, int, int]:
    prefix = "read-" if function == 23 else ""
    wrong = ("address", "quantity", "table") if function == 23 else \
        ("read-address", "read-quantity", "read-table", "write-address", "write-quantity",
         "write-table")
    for key in wrong:
        if f.has(key):
            raise ConfigError(f"{f.label}: {key}: not for function {function}" +
                              (" (write read-address, read-quantity, read-table, "
                               "write-address, write-quantity, write-table)"
                               if function == 23 else ""))
    bits = function in BIT_FUNCTIONS
    limit = BITS if bits else REGISTERS
    low, high = QUANTITY_RANGES[function]
    address = f.integer(f"{prefix}address", 0, limit - 1, bits=bits)
    quantity = f.integer(f"{prefix}quantity", low, high, default=1 if low == high else None)
    if address + quantity > limit:
        raise f.error(f"{prefix}quantity", quantity,
                      f"from {prefix}address {address} it goes beyond the device's last "
                      f"{'bit' if bits else 'register'} ({limit - 1})")
    table = f.integer(f"{prefix}table", 0, limit - 1, bits=bits)
    end = (table + quantity - 1) // 16 + 1 if bits else table + quantity
    if end > REGISTERS:
        raise f.error(f"{prefix}table", f.fields[f"{prefix}table"],
                      f"with quantity {quantity} it goes beyond the table")
    if function in READS and end > CONFIG_ZONE_FIRST:
        raise f.error(f"{prefix}table", f.fields[f"{prefix}table"],
                      f"a read with quantity {quantity} would store into the configuration "
                      f"zone (0x8000-0xFFFF), which is read-only")
    return address, quantity, table


def _write_part(f: _Fields) -> tuple[int, int, int]:
    address = f.integer("write-address", 0, REGISTERS - 1)
    quantity = f.integer("write-quantity", *WRITE_QUANTITY_RANGE_23)
    if address + quantity > REGISTERS:
        raise f.error("write-quantity", quantity, f"from write-address {address} it goes "
                                                  f"beyond the device's last register")
    table = f.integer("write-table", 0, REGISTERS - 1)
    if table + quantity > REGISTERS:
        raise f.error("write-table", table, f"with write-quantity {quantity} it goes beyond "
                                            f"the table")
    return address, quantity, table


def _trigger(f: _Fields, function: int) -> tuple[int | None, bool]:
    if f.has("cycle") == f.has("trigger"):
        raise ConfigError(f"{f.label}: give cycle (ms, {CYCLE_RANGE[0]}..{CYCLE_RANGE[1]}) or "
                          f"trigger = \"change\"" + (", not both" if f.has("cycle") else ""))
    if f.has("cycle"):
        return f.integer("cycle", *CYCLE_RANGE), False
    value = f.fields["trigger"]
    if value != TRIGGER_CHANGE:
        raise f.error("trigger", value, "expected \"change\" (or a cycle in ms)")
    if function not in WRITES:
        raise f.error("trigger", value, f"only a write is sent on change; function "
                                        f"{function} ({FUNCTION_NAMES[function]}) needs a "
                                        f"cycle")
    return None, True


def check_scenarios(scenarios, mode: str) -> list[str]:
    """What is wrong with a mode's list of scenarios as a whole: duplicate names, more than
    MAX_PER_KIND of a kind, serial scenarios in master or transparent mode, one TLS server
    pinned two ways."""
    problems = []
    where: dict[str, list[int]] = {}
    for number, sc in enumerate(scenarios, 1):
        where.setdefault(sc.name, []).append(number)
    for name, numbers in where.items():
        if len(numbers) > 1:
            problems.append(f"scenario {name}: name used by {len(numbers)} scenarios (the "
                            f"{_ordinals(numbers)} [[scenario]] tables); each needs its own")
    pinned: dict[str, ScenarioConfig] = {}
    for sc in scenarios:
        if sc.tls and sc.server is not None:
            host = split_server(sc.server)[0]
            other = pinned.setdefault(host, sc)
            if other.fingerprint != sc.fingerprint:
                problems.append(f"scenario {sc.name}: fingerprint: server {host} is pinned "
                                f"otherwise by scenario {other.name} (one certificate per "
                                f"server)")
    for kind in ("serial", "tcp"):
        count = sum(1 for sc in scenarios if sc.kind == kind)
        if count > MAX_PER_KIND:
            problems.append(f"scenario: {count} {kind} scenarios, at most {MAX_PER_KIND}")
    serial = [sc.name for sc in scenarios if sc.kind == "serial"]
    if mode == "master" and serial:
        problems.append(f"scenario {serial[0]}: slave: a serial scenario needs the line's "
                        f"master role, which master mode gives to TCP clients; use slave "
                        f"mode, or a TCP scenario (server)")
    if mode == "transparent" and serial:
        problems.append(f"scenario {serial[0]}: slave: transparent mode's line carries raw "
                        f"frames, not Modbus; only TCP scenarios (server) run beside it")
    return problems


def overlaps(scenarios) -> list[str]:
    """Warnings: two read scenarios that store into the same table registers (the later
    read overwrites the other's data)."""
    reads = [(sc, sc.read_range()) for sc in scenarios if sc.reads and sc.enabled]
    found = []
    for i, (one, (first, count)) in enumerate(reads):
        for other, (first2, count2) in reads[i + 1:]:
            low, high = max(first, first2), min(first + count, first2 + count2) - 1
            if low <= high:
                shared = f"{low}" if low == high else f"{low}-{high}"
                found.append(f"scenario {other.name}: stores into table registers {shared}, "
                             f"as scenario {one.name} does: each overwrites the other's data")
    return found


def _ordinals(numbers: list[int]) -> str:
    words = [f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"
             for n in numbers]
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def parse_scenarios(entries, mode: str) -> tuple[tuple[ScenarioConfig, ...], list[str]]:
    """The file's `scenario` array: the scenarios, and every problem found (each naming its
    scenario and key; the Nth [[scenario]] table when two have the same name)."""
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        return (), ["scenario: expected [[scenario]] tables"]
    names = [e.get("name") for e in entries]
    scenarios, problems = [], []
    for number, entry in enumerate(entries, 1):
        name = entry.get("name")
        label = f"scenario {name} (the {_ordinals([number])} [[scenario]] table)" \
            if isinstance(name, str) and names.count(name) > 1 else None
        try:
            scenarios.append(parse_scenario(entry, f"scenario {number}", label))
        except ScenarioError as err:
            problems += err.problems
    if not problems:
        problems = check_scenarios(scenarios, mode)
    return tuple(scenarios), problems
