"""The `[[line]]` and `[[route]]` tables of the configuration file, checked key by key.

A `[[line]]` takes every `[serial]` key, checked by the same option as under `[serial]` (of
the line's own mode's command), plus `name` and `mode`.  Its values are handed on converted
as the command line would give them (`LineTable.params`, by parameter name), for the mode
command to build its LineConfig.  A `[[route]]` becomes a RouteConfig at once.  What only the
whole configuration can check (unknown lines, overlaps, rewrites) is
`route_checks.route_problems`'.  `connect` is parsed here too (`parse_connect`)."""
import difflib
from dataclasses import dataclass, field
from functools import partial

from mbgw.config.cache import parse_cache
from mbgw.config.lines import (
    LINE_KINDS,
    LINE_MODES,
    MAX_LINES,
    MAX_ROUTES,
    NAME_PATTERN,
    PRIMARY_LINE,
    TCP_FACE,
    DeviceConfig,
    RemoteTarget,
    RouteConfig,
)
from mbgw.config.model import (
    DOWN_AFTER_RANGE,
    PAUSE_RANGE,
    PROBE_INTERVAL_RANGE,
    RETRIES_RANGE,
    STOUT_RANGE,
)
from mbgw.config.number_list import number_list_text, parse_number_list
from mbgw.config.schema import Schema, default_value
from mbgw.config.server_address import DEFAULT_SERVER_PORT, DEFAULT_TLS_SERVER_PORT, split_server
from mbgw.config.slaveid import parse_fingerprint
from mbgw.config.tables import check_keys, parse_each, typed
from mbgw.config.values import Problem, check_value, process, to_click
from mbgw.errors import ConfigError

LINE_TABLE = "line"
ROUTE_TABLE = "route"
DEVICE_TABLE = "device"
LINES_PARAM = "lines"            # the mode commands' hidden parameters the file fills
ROUTES_PARAM = "routes"
MONITORS_PARAM = "monitors"
DEVICES_PARAM = "devices"
LINE_OWN_KEYS = ("name", "mode")
# a remote line's own keys (`connect`: a device across the network instead of `device`)
REMOTE_KEYS = ("connect", "connect-delay", "pause")
# `connect`'s schemes: a line that is a device across the network, and how its frames travel
REMOTE_KINDS = ("modbus-tcp", "rtu-over-tcp", "ascii-over-tcp", "rtu-over-udp", "modbus-udp")
CONNECT_DELAY_RANGE = (0, 65535)   # ms after each TCP connection before the first request
# what a remote line takes from [serial] when its table leaves them out
SERIAL_DEFAULTS = ("stout", "retries", "down-after", "probe-interval")
# the serial port's own keys, which a remote line has no use for
PORT_KEYS = ("device", "baudrate", "format", "interface", "rtsdelays", "dtr", "rts", "cts",
             "xonxoff", "silence", "protocol", "ascii-timeout", "interframe-silence")
MASTER_LINE_REFUSED = ("stout", "nocheck")      # as `mbgw master --stout` is refused
# a line in monitor mode takes a master-mode line's keys: the port's settings, no timing
LISTENING_KEYS_OF = {"monitor": "master"}
ROUTE_KEYS = ("units", "line", "table", "server", "offset", "address", "from", "tls",
              "fingerprint", "cache")
TCP_UNITS = (1, 255)             # as [table] units
SERIAL_ADDRESSES = (1, 247)      # a serial face's addresses
# a [[device]]'s timing keys: (field of DeviceConfig, bounds, as the [serial] key's)
DEVICE_TIMING = {"stout": ("stout_ms", STOUT_RANGE), "retries": ("retries", RETRIES_RANGE),
                 "pause": ("pause_ms", PAUSE_RANGE),
                 "down-after": ("down_after", DOWN_AFTER_RANGE),
                 "probe-interval": ("probe_interval_ms", PROBE_INTERVAL_RANGE)}
DEVICE_KEYS = ("line", "unit", *DEVICE_TIMING)
OFFSET_RANGE = (-254, 254)
ADDRESS_RANGE = (0, 255)


@dataclass(frozen=True)
class LineTable:
    """One checked [[line]]: its name, mode, and its [serial] keys' values as the line's mode
    command receives them (parameter name -> value, defaults filled in)."""
    name: str
    mode: str
    params: dict = field(default_factory=dict)
    keys: dict = field(default_factory=dict)     # as written: key name -> TOML value
    remote: RemoteTarget | None = None           # connect
    connect_delay_ms: int = 0
    pause_ms: int = 0


def parse_lines(schema: Schema, found: list[dict], daemon_mode: str
                ) -> tuple[tuple[LineTable, ...], list[str]]:
    problems: list[str] = []
    if len(found) > MAX_LINES:
        problems.append(f"line: {len(found)} [[line]] tables, at most {MAX_LINES}")
    lines = []
    for index, fields in enumerate(found, 1):
        line = _parse_line(schema, fields, index, problems)
        if line is not None:
            lines.append(line)
    if found and daemon_mode not in LINE_MODES:
        problems.append(f"line: [[line]] tables are for slave and master modes; {daemon_mode} "
                        f"mode bridges [serial] only")
    return tuple(lines), problems


def _parse_line(schema: Schema, fields: dict, index: int, problems: list[str]
                ) -> LineTable | None:
    name = fields.get("name")
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        problems.append(f"line {index}.name: " + (
            "missing; every [[line]] has a name" if name is None else
            f"{name!r}: expected 1 to 32 of a-z, 0-9 and -, beginning with a letter or digit"))
        return None
    label = f"line {name}"
    if name == PRIMARY_LINE:
        problems.append(f"{label}.name: {PRIMARY_LINE!r} is [serial]'s name, reserved")
        return None
    mode = fields.get("mode", "slave")
    if mode not in LINE_KINDS:
        problems.append(f"{label}.mode: expected \"slave\" (mbgw is the master on the line), "
                        f"\"master\" (a master is on it) or \"monitor\" (mbgw only listens), "
                        f"got {mode!r}")
        return None
    keys_of = LISTENING_KEYS_OF.get(mode, mode)
    before = len(problems)
    remote = _remote(label, mode, fields, problems)
    for key_name, value in fields.items():
        if key_name in LINE_OWN_KEYS or key_name in REMOTE_KEYS:
            continue
        if "connect" in fields and key_name in PORT_KEYS:
            problems.append(f"{label}.{key_name}: a serial port's key; the line is "
                            f"connect = {fields['connect']!r}")
            continue
        key = schema.find("serial", key_name)
        if key is None:
            problems.append(f"{label}.{key_name}: unknown key" + _line_hint(schema, key_name))
        elif keys_of not in key.params or (keys_of == "master"
                                           and key_name in MASTER_LINE_REFUSED):
            problems.append(f"{label}.{key_name}: applies to slave-mode lines only")
        else:
            problems += check_value(schema, key, keys_of, value, f"{label}.{key_name}")
    if "device" not in fields and "connect" not in fields:
        problems.append(f"{label}.device: missing; every line needs its device (or connect)")
    if len(problems) > before:
        return None
    return LineTable(name, mode, _params(schema, fields, keys_of),
                     {k: v for k, v in fields.items() if k not in LINE_OWN_KEYS},
                     remote, fields.get("connect-delay", 0), fields.get("pause", 0))


def _remote(label: str, mode: str, fields: dict, problems: list[str]) -> RemoteTarget | None:
    """connect, connect-delay and pause, checked (a remote line is a target: slave mode)."""
    if "connect" not in fields:
        problems += [f"{label}.{k}: only with connect = \"KIND://HOST:PORT\""
                     for k in REMOTE_KEYS if k in fields]
        return None
    remote = None
    try:
        text = typed(label, fields, "connect", str, "\"KIND://HOST:PORT\"")
        remote = parse_connect(f"{label}.connect", text)
        for key, (low, high) in (("connect-delay", CONNECT_DELAY_RANGE),
                                 ("pause", PAUSE_RANGE)):
            value = typed(label, fields, key, int, "an integer (ms)", 0)
            if not low <= value <= high:
                raise ConfigError(f"{label}.{key}: {value} out of range {low}..{high}")
    except ConfigError as err:
        problems.append(str(err))
    if mode != "slave":
        problems.append(f"{label}.connect: a remote line is a target (mode = \"slave\"), "
                        f"got mode {mode!r}")
    return remote


def parse_connect(label: str, text: str) -> RemoteTarget:
    """`KIND://HOST:PORT` (PORT 502 by default for modbus-tcp and modbus-udp)."""
    kind, sep, rest = text.partition("://")
    if not sep or kind not in REMOTE_KINDS:
        raise ConfigError(f"{label}: {text!r}: expected KIND://HOST:PORT, KIND one of "
                          f"{', '.join(REMOTE_KINDS)}")
    host, port_text = rest, ""
    if rest.startswith("["):
        host, _, tail = rest[1:].partition("]")
        port_text = tail.removeprefix(":")
    elif rest.count(":") == 1:
        host, port_text = rest.split(":")
    if not host:
        raise ConfigError(f"{label}: {text!r}: no host")
    if not port_text:
        if kind not in ("modbus-tcp", "modbus-udp"):
            raise ConfigError(f"{label}: {text!r}: give the port, e.g. {kind}://{host}:4001")
        port_text = str(DEFAULT_SERVER_PORT)
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ConfigError(f"{label}: {text!r}: port {port_text!r} is not 1..65535")
    return RemoteTarget(kind, host, int(port_text))


def line_keys(schema: Schema) -> list[str]:
    """The keys a [[line]] may have, beside name and mode."""
    return [name for name in schema.group_keys("serial") if name in schema.keys]


def _line_hint(schema: Schema, name: str) -> str:
    match = difflib.get_close_matches(name.lower(), [*LINE_OWN_KEYS, *line_keys(schema)], n=1,
                                      cutoff=0.6)
    return f"; did you mean {match[0]}?" if match else ""


def _params(schema: Schema, fields: dict, mode: str) -> dict:
    """The line's [serial] keys as its mode command's parameters, the file's or the default."""
    params = {}
    command = schema.commands[mode]
    for name in line_keys(schema):
        key = schema.keys[name]
        param = key.params.get(mode)
        if param is None or param.name is None:
            continue
        value = fields[name] if name in fields else default_value(schema, name, mode)
        try:
            params[param.name] = process(command, param, None if value is None else
                                         to_click(name, param, value))
        except Problem:             # a default the option refuses: the device, required
            params[param.name] = None
    return params


def parse_routes(found: list[dict]) -> tuple[tuple[RouteConfig, ...], list[str]]:
    too_many = [f"route: {len(found)} [[route]] tables, at most {MAX_ROUTES}"] \
        if len(found) > MAX_ROUTES else []
    routes, problems = parse_each(found, _parse_route)
    return routes, too_many + problems


def _parse_route(index: int, fields: dict) -> RouteConfig:
    label = f"route {index}"
    check_keys(label, fields, ROUTE_KEYS)
    key = partial(typed, label, fields)
    face = key("from", str, "a line name", TCP_FACE)
    if "from" in fields and face == TCP_FACE:
        raise ConfigError(f"{label}.from: expected a line name, got \"\"")
    units_value = fields.get("units")
    if units_value is None:
        raise ConfigError(f"{label}.units: missing; e.g. units = \"32-63\"")
    if not isinstance(units_value, (str, int)) or isinstance(units_value, bool):
        raise ConfigError(f"{label}.units: expected numbers and ranges, e.g. \"1,5,32-63\", got "
                          f"{units_value!r}")
    low, high = TCP_UNITS if face == TCP_FACE else SERIAL_ADDRESSES
    try:
        units = parse_number_list(f"{label}.units", str(units_value), low, high)
    except ConfigError as err:
        raise ConfigError(str(err).replace(f"{label}.units ", f"{label}.units: ", 1)) from None
    server_address, tls, fingerprint = _server(label, key)
    offset = key("offset", int, "an integer", 0)
    if not OFFSET_RANGE[0] <= offset <= OFFSET_RANGE[1]:
        raise ConfigError(f"{label}.offset: {offset} out of range {OFFSET_RANGE[0]}.."
                          f"{OFFSET_RANGE[1]}")
    address = key("address", int, "an integer")
    if address is not None and not ADDRESS_RANGE[0] <= address <= ADDRESS_RANGE[1]:
        raise ConfigError(f"{label}.address: {address} out of range {ADDRESS_RANGE[0]}.."
                          f"{ADDRESS_RANGE[1]}")
    return RouteConfig(index=index, units=units, face=face,
                       line=key("line", str, "a line name"),
                       table=key("table", bool, "true or false", False),
                       server=server_address, offset=offset, address=address, tls=tls,
                       fingerprint=fingerprint, cache=_route_cache(label, fields))


def _route_cache(label: str, fields: dict):
    """A route's cache: its own rule, False (off), or None (not given: the line's)."""
    if "cache" not in fields:
        return None
    try:
        return parse_cache(fields["cache"]) or False
    except ConfigError as err:
        raise ConfigError(f"{label}.cache: {err}") from None


def parse_devices(found: list[dict]) -> tuple[tuple[DeviceConfig, ...], list[str]]:
    return parse_each(found, _parse_device)


def _parse_device(index: int, fields: dict) -> DeviceConfig:
    label = f"device {index}"
    check_keys(label, fields, DEVICE_KEYS)
    key = partial(typed, label, fields)
    unit = key("unit", int, "a serial address")
    if unit is None:
        raise ConfigError(f"{label}.unit: missing; the serial address, e.g. unit = 5")
    low, high = SERIAL_ADDRESSES
    if not low <= unit <= high:
        raise ConfigError(f"{label}.unit: {unit} out of range {low}..{high}")
    timing = {}
    for name, (attribute, (low, high)) in DEVICE_TIMING.items():
        value = key(name, int, "an integer (ms)" if attribute.endswith("_ms") else "an integer")
        if value is not None and not low <= value <= high:
            raise ConfigError(f"{label}.{name}: {value} out of range {low}..{high}")
        if value is not None:
            timing[attribute] = value
    return DeviceConfig(index=index, unit=unit,
                        line=key("line", str, "a line name", PRIMARY_LINE), **timing)


def device_fields(device: DeviceConfig) -> dict:
    """A device as the keys of its [[device]] table."""
    fields: dict = {"line": device.line, "unit": device.unit}
    for name, (attribute, _) in DEVICE_TIMING.items():
        value = getattr(device, attribute)
        if value is not None and (value or name != "pause"):
            fields[name] = value
    return fields


def _server(label: str, key) -> tuple[tuple[str, int] | None, bool, bytes | None]:
    """A route's server = "IP[:PORT]" (502, or 802 with tls = true, when left out), tls and
    fingerprint, as a TCP scenario's."""
    server = key("server", str, "\"IP[:PORT]\"")
    tls = key("tls", bool, "true or false", False)
    address = None
    if server is not None:
        try:
            address = split_server(server, DEFAULT_TLS_SERVER_PORT if tls
                                   else DEFAULT_SERVER_PORT)
        except ConfigError as err:
            raise ConfigError(f"{label}.server: {err}") from None
    elif tls:
        raise ConfigError(f"{label}.tls: only with server = \"IP[:PORT]\"")
    fingerprint = key("fingerprint", str, "the server certificate's SHA-256 fingerprint")
    if fingerprint is not None and not tls:
        raise ConfigError(f"{label}.fingerprint: only with tls = true")
    pin = parse_fingerprint(f"{label}.fingerprint", fingerprint) \
        if fingerprint is not None else None
    return address, tls, pin


def table_units_overlap(values: dict, routes: tuple[RouteConfig, ...]) -> list[str]:
    """[table] units written in the file and a `table = true` route on the TCP face: both
    take units to the table."""
    if "units" not in values:
        return []
    return [f"{r.label}.table: table.units routes units to the table already; both at once "
            f"is an overlap (remove one)" for r in routes if r.table and r.face == TCP_FACE]


def line_fields(line: LineTable) -> dict:
    """A [[line]] as its table's keys: name, mode, then the keys the file gives."""
    return {"name": line.name, "mode": line.mode, **line.keys}


def route_fields(route: RouteConfig) -> dict:
    """A route as the keys of its [[route]] table (what parse_routes reads)."""
    fields: dict = {"units": number_list_text(route.units)}
    if route.face != TCP_FACE:
        fields["from"] = route.face
    if route.line is not None:
        fields["line"] = route.line
    if route.table:
        fields["table"] = True
    if route.server is not None:
        fields["server"] = route.target.removeprefix("server ")
    if route.tls:
        fields["tls"] = True
    if route.fingerprint is not None:
        fields["fingerprint"] = route.fingerprint.hex(":").upper()
    if route.offset:
        fields["offset"] = route.offset
    if route.address is not None:
        fields["address"] = route.address
    if route.cache is not None:
        fields["cache"] = route.cache.fields if route.cache else False
    return fields
