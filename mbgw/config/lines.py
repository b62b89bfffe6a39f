"""Lines, faces, routes and targets: the settings of a daemon with more than one line.

A *face* is where requests come in: the Modbus TCP listeners (`TCP_FACE`) or a line in master
mode (an outside master on it: its serial-slave face).  A *target* is where a request is
answered: a line in slave mode (mbgw is the master on it), the exchange table, or a remote
Modbus TCP server.  A *route* takes a face's units (serial addresses, on a serial face) to a
target, each rewritten on the way (an offset, or one fixed address).

`[serial]` is the first line, named `serial`; `[[line]]` tables add more, `[[route]]` tables
the routes.  Without a route for a face, the face keeps today's routing (`implicit` routes).
"""
import ipaddress
import re
from dataclasses import dataclass, field

from mbgw.config.cache import CacheRule, RouteCache
from mbgw.config.model import (
    DEFAULT_TURNAROUND_MS,
    Demotion,
    MasterConfig,
    SerialConfig,
    SlaveConfig,
)
from mbgw.config.number_list import number_list_text
from mbgw.errors import ConfigError
from mbgw.protocol import pdu

PRIMARY_LINE = "serial"            # [serial]'s name; reserved for it
TCP_FACE = ""                      # the face of the Modbus TCP listeners (plain and TLS)
LINE_MODES = ("slave", "master")   # slave: mbgw masters the line; master: a master is on it
LINE_KINDS = (*LINE_MODES, "monitor")   # a [[line]]'s; monitor: mbgw only listens
NAME_PATTERN = re.compile(r"[a-z0-9][a-z0-9-]{0,31}")
MAX_LINES = 32
MAX_ROUTES = 256
DEFAULT_SERVER_PORT = 502
MAX_SERVER_UNIT = 255
# `connect`'s schemes: a line that is a device across the network, and how its frames travel
REMOTE_KINDS = ("modbus-tcp", "rtu-over-tcp", "ascii-over-tcp", "rtu-over-udp", "modbus-udp")
CONNECT_DELAY_RANGE = (0, 65535)   # ms after each TCP connection before the first request


@dataclass(frozen=True)
class RemoteTarget:
    """Where a remote line's device is (`connect = "KIND://HOST:PORT"`)."""
    kind: str
    host: str
    port: int

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.kind}://{host}:{self.port}"

    @property
    def mbap(self) -> bool:
        """Modbus TCP framing (MBAP header, transaction ids), not the serial line's."""
        return self.kind in ("modbus-tcp", "modbus-udp")

    @property
    def datagrams(self) -> bool:
        return self.kind.endswith("-udp")


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


@dataclass(frozen=True)
class LineConfig:
    """One serial line: its port settings, who is master on it, its timing and demotion."""
    name: str
    serial: SerialConfig
    mode: str = "slave"
    retries: int = 0
    demotion: Demotion = field(default_factory=Demotion)
    turnaround_ms: int = DEFAULT_TURNAROUND_MS   # slave mode: the pause after a broadcast
    late_window_ms: int | None = None            # slave mode: None: stout
    remote: RemoteTarget | None = None           # `connect`: a device across the network
    connect_delay_ms: int = 0                    # remote over TCP: wait after connecting
    cache: CacheRule | None = None               # slave mode: reads shared and kept

    def __post_init__(self) -> None:
        if self.name != PRIMARY_LINE and not NAME_PATTERN.fullmatch(self.name):
            raise ConfigError(f"line {self.name!r}: name: expected 1 to 32 of a-z, 0-9 and -, "
                              f"beginning with a letter or digit")
        if self.mode not in LINE_KINDS:
            raise ConfigError(f"line {self.name}.mode {self.mode!r}: expected slave (mbgw is "
                              f"the master on the line), master (a master is on it) or "
                              f"monitor (mbgw only listens)")

    @property
    def is_target(self) -> bool:
        return self.mode == "slave"

    @property
    def is_face(self) -> bool:
        return self.mode == "master"

    @property
    def is_monitor(self) -> bool:
        """Neither face nor target: mbgw never transmits on it."""
        return self.mode == "monitor"


@dataclass(frozen=True)
class RouteConfig:
    """A face's units to one target.  Exactly one of line, table, server is set."""
    index: int                     # its place among the [[route]] tables, from 1 (0: implicit)
    units: tuple[int, ...]
    face: str = TCP_FACE           # `from`: a line in master mode; TCP_FACE: the listeners
    line: str | None = None
    table: bool = False
    server: tuple[str, int] | None = None   # (host, port)
    offset: int = 0
    address: int | None = None     # one fixed address (ACKSYS's slaveid)
    implicit: bool = False         # today's routing, shown as a route (slaveid, [table] units)
    gateway: bool = False          # general.gateway-unit: the table's identity functions only
    tls: bool = False              # server: reached over TLS (a slaveid range's `tls`)
    fingerprint: bytes | None = None   # server: its certificate's pinned SHA-256
    cache: RouteCache = None       # to a line: its own (False: off; None: the line's)

    @property
    def label(self) -> str:
        if not self.implicit:
            return f"route {self.index}"
        if self.gateway:
            return "general.gateway-unit"
        if self.table:
            return "table.units" if self.face == TCP_FACE else "table.address"
        return "net.slaveid" if self.server is not None else "implicit route"

    @property
    def target(self) -> str:
        """The target as status shows it: line NAME, table, server HOST:PORT."""
        if self.line is not None:
            return f"line {self.line}"
        if self.gateway:
            return "gateway"
        if self.table:
            return "table"
        assert self.server is not None
        host, port = self.server
        return f"server {'[' + host + ']' if ':' in host else host}:{port}"

    def rewrite(self, unit: int) -> int:
        """The unit or address the target is sent for unit."""
        return self.address if self.address is not None else unit + self.offset


@dataclass(frozen=True)
class DeviceConfig:
    """A [[device]]: one serial address's own timing on a line in slave mode; what is None
    is the line's."""
    index: int                     # its place among the [[device]] tables, from 1
    unit: int
    line: str = PRIMARY_LINE
    stout_ms: int | None = None
    retries: int | None = None
    pause_ms: int = 0              # the line quiet at least this long before each frame to it
    down_after: int | None = None
    probe_interval_ms: int | None = None

    @property
    def label(self) -> str:
        return f"device {self.index}"

    def demotion(self, line: Demotion) -> Demotion:
        """Its demotion: its own down-after and probe-interval, the line's for the rest."""
        return Demotion(line.down_after if self.down_after is None else self.down_after,
                        line.probe_interval_ms if self.probe_interval_ms is None
                        else self.probe_interval_ms)


def line_devices(devices: tuple[DeviceConfig, ...], name: str) -> tuple[DeviceConfig, ...]:
    """The [[device]] tables of line `name`."""
    return tuple(d for d in devices if d.line == name)


def device_problems(lines: tuple[LineConfig, ...], routes: tuple[RouteConfig, ...],
                    devices: tuple[DeviceConfig, ...]) -> list[str]:
    """A [[device]] on no line, on a line in master mode, twice for one (line, unit), or for
    a unit no route reaches."""
    by_name = {line.name: line for line in lines}
    reached = {(r.line, r.rewrite(u)) for r in routes if r.line is not None for u in r.units}
    problems: list[str] = []
    seen: dict[tuple[str, int], DeviceConfig] = {}
    for device in devices:
        label, line = device.label, by_name.get(device.line)
        if line is None:
            problems.append(f"{label}.line {device.line!r}: no such line")
        elif not line.is_target:
            problems.append(f"{label}.line {device.line!r}: the line is in master mode; "
                            f"[[device]] is for a line in slave mode (mbgw the master on it)")
        elif (device.line, device.unit) in seen:
            problems.append(f"{label}.unit: unit {device.unit} of line {device.line} has "
                            f"{seen[device.line, device.unit].label} already")
        elif (device.line, device.unit) not in reached:
            problems.append(f"{label}.unit: no route reaches unit {device.unit} of line "
                            f"{device.line}")
        seen.setdefault((device.line, device.unit), device)
    return problems


def route_problems(lines: tuple[LineConfig, ...], routes: tuple[RouteConfig, ...]) -> list[str]:
    """What check-config refuses in lines and routes, each naming its key."""
    problems: list[str] = []
    by_name = _named(lines, problems)
    taken: dict[tuple[str, int], RouteConfig] = {}
    for route in routes:
        if route.gateway:
            continue
        found = _route_problems(route, by_name)
        problems += found
        if found and found[0].startswith(f"{route.label}: give one target"):
            continue
        for unit in route.units:
            other_route = taken.get((route.face, unit))
            if other_route is not None:
                problems.append(f"{route.label}.units: unit {unit} is routed by "
                                f"{other_route.label} already")
                break
            taken[(route.face, unit)] = route
    for route in routes:
        other_route = taken.get((route.face, route.units[0])) if route.gateway else None
        if other_route is not None:
            problems.append(f"general.gateway-unit: unit {route.units[0]} is routed by "
                            f"{other_route.label} already; give one no route and not the "
                            f"table takes")
    return problems


def _named(lines: tuple[LineConfig, ...], problems: list[str]) -> dict[str, LineConfig]:
    """The lines by name; two with one name, or two on one device, are problems."""
    by_name: dict[str, LineConfig] = {}
    by_device: dict[str, str] = {}
    for line in lines:
        if line.name in by_name:
            problems.append(f"line {line.name}.name: two lines are named {line.name!r}")
        by_name[line.name] = line
        other = by_device.get(line.serial.device)
        if other is not None:
            problems.append(f"line {line.name}.device {line.serial.device}: line {other} "
                            f"uses it already")
        by_device.setdefault(line.serial.device, line.name)
    return by_name


def _route_problems(route: RouteConfig, by_name: dict[str, LineConfig]) -> list[str]:
    label = route.label
    targets = [n for n, given in (("line", route.line is not None), ("table", route.table),
                                  ("server", route.server is not None)) if given]
    if len(targets) != 1:
        return [f"{label}: give one target: line = NAME, table = true or server = "
                f"\"IP[:PORT]\"" + (f" (got {' and '.join(targets)})" if targets else "")]
    problems = []
    if route.address is not None and route.offset:
        problems.append(f"{label}.offset: offset and address exclude each other")
    if route.face != TCP_FACE:
        face = by_name.get(route.face)
        if face is None:
            problems.append(f"{label}.from {route.face!r}: no such line")
        elif not face.is_face:
            problems.append(f"{label}.from {route.face!r}: the line is in {face.mode} mode; "
                            f"from names a line in master mode (a master on it)")
    if route.line is not None:
        problems += _line_target_problems(route, by_name.get(route.line))
    elif route.cache is not None:
        problems.append(f"{label}.cache: only a route to a line in slave mode has a cache "
                        f"(the table answers at once; a server's reads are not cached)")
    if not route.implicit and (route.line is not None or route.server is not None):
        problems += _rewrite_problems(route)
    return problems


def _line_target_problems(route: RouteConfig, target: LineConfig | None) -> list[str]:
    label = route.label
    if target is None:
        return [f"{label}.line {route.line!r}: no such line"]
    if not target.is_target:
        return [f"{label}.line {route.line!r}: the line is in {target.mode} mode; a route "
                f"reaches a line in slave mode (mbgw the master on it)"]
    if route.line == route.face:
        return [f"{label}.line {route.line!r}: a line cannot route to itself"]
    return []


def _rewrite_problems(route: RouteConfig) -> list[str]:
    """A unit rewritten outside the target's addresses: 1..247 on a line, 0..255 on a
    server."""
    high = MAX_SERVER_UNIT if route.server is not None else pdu.MAX_SERIAL_ADDRESS
    low = 0 if route.server is not None else 1
    bad = [u for u in route.units if not low <= route.rewrite(u) <= high]
    if not bad:
        return []
    if route.address is None and not route.offset:
        return [f"{route.label}.units: unit {bad[0]} is outside {low}..{high}, the target's "
                f"addresses; give offset or address"]
    key = "address" if route.address is not None else "offset"
    return [f"{route.label}.{key}: unit {bad[0]} becomes {route.rewrite(bad[0])}, outside "
            f"{low}..{high}"]


def check_routes(lines: tuple[LineConfig, ...], routes: tuple[RouteConfig, ...]) -> None:
    problems = route_problems(lines, routes)
    if problems:
        raise ConfigError(problems[0])


class RouteMap:
    """Each face's 256 units, each to its route (None: no route takes it).  Built once per
    configuration; lookups are one list index, made on the request path."""

    def __init__(self, routes: tuple[RouteConfig, ...]) -> None:
        self.routes = routes
        self._faces: dict[str, list[RouteConfig | None]] = {}
        for route in routes:
            units = self._faces.setdefault(route.face, [None] * 256)
            for unit in route.units:
                units[unit] = route

    def faces(self) -> list[str]:
        return list(self._faces)

    def has_face(self, face: str) -> bool:
        return face in self._faces

    def units(self, face: str) -> list[RouteConfig | None]:
        """face's routes by unit (every entry None when the face has none)."""
        return self._faces.get(face) or [None] * 256


ALL_UNITS = tuple(range(256))


def implicit_routes(cfg: SlaveConfig | MasterConfig) -> tuple[RouteConfig, ...]:
    """Today's routing, as routes, for each face without an explicit route (implicit=True).
    Slave mode's TCP face: the table's units to the table, every other unit to line serial
    (at the fixed `slaveid` address when it is set; none when [serial] is left out).  Master
    mode's serial face: the slaveid ranges to their servers, the table's serial address to
    the table.  A face with explicit routes keeps only its table route, unless one of its
    routes is `table = true`."""
    if isinstance(cfg, SlaveConfig):
        return _slave_routes(cfg)
    return _master_routes(cfg)


def _explicit(cfg: SlaveConfig | MasterConfig, face: str) -> tuple[bool, bool]:
    """(the face has explicit routes, one of them is to the table)."""
    own = [r for r in cfg.routes if r.face == face]
    return bool(own), any(r.table for r in own)


def gateway_routes(cfg: SlaveConfig | MasterConfig, tcp_face: bool) -> list[RouteConfig]:
    """general.gateway-unit on every face: the TCP face's (tcp_face: the daemon has one) and
    each serial face's (line serial in master mode, each line in master mode)."""
    unit = cfg.gateway_unit
    if not unit:
        return []
    faces = [TCP_FACE] if tcp_face else []
    if isinstance(cfg, MasterConfig):
        faces.append(PRIMARY_LINE)
    faces += [line.name for line in cfg.lines if line.is_face]
    return [RouteConfig(0, (unit,), face=face, gateway=True, implicit=True) for face in faces]


def _slave_routes(cfg: SlaveConfig) -> tuple[RouteConfig, ...]:
    explicit, explicit_table = _explicit(cfg, TCP_FACE)
    routes = gateway_routes(cfg, tcp_face=True)
    table_units: tuple[int, ...] = ()
    gateway: tuple[int, ...] = (cfg.gateway_unit,) if cfg.gateway_unit else ()
    if cfg.table_on and not explicit_table:
        table_units = cfg.table.units if cfg.table.direct else ALL_UNITS
        routes.append(RouteConfig(0, table_units, table=True, implicit=True))
    if not explicit and cfg.serial_line and len(table_units) + len(gateway) < len(ALL_UNITS):
        taken = {*table_units, *gateway}
        routes.append(RouteConfig(0, tuple(u for u in ALL_UNITS if u not in taken),
                                  line=PRIMARY_LINE, address=cfg.slaveid or None,
                                  implicit=True))
    return tuple(routes)


def _master_routes(cfg: MasterConfig) -> tuple[RouteConfig, ...]:
    explicit, explicit_table = _explicit(cfg, PRIMARY_LINE)
    routes = gateway_routes(cfg, tcp_face=any(r.face == TCP_FACE for r in cfg.routes))
    if cfg.table.enabled and cfg.table.address and not explicit_table:
        routes.append(RouteConfig(0, (cfg.table.address,), face=PRIMARY_LINE, table=True,
                                  implicit=True))
    if explicit:
        return tuple(routes)
    for r in cfg.slaveid.ranges:
        addresses = range(r.first, r.last + 1)
        units = [r.remote_first + step if r.remote_first else 0xFF
                 for step in range(len(addresses))]
        if not r.variable_ip:
            routes.append(RouteConfig(
                0, tuple(addresses), face=PRIMARY_LINE, server=(str(r.ip), cfg.mdbport),
                offset=r.remote_first - r.first if r.remote_first else 0,
                address=None if r.remote_first else 0xFF, implicit=True, tls=r.tls,
                fingerprint=r.fingerprint))
            continue
        for step, address in enumerate(addresses):
            host = str(ipaddress.IPv4Address(int(r.ip) + step))
            routes.append(RouteConfig(0, (address,), face=PRIMARY_LINE,
                                      server=(host, cfg.mdbport), address=units[step],
                                      implicit=True, tls=r.tls, fingerprint=r.fingerprint))
    return tuple(routes)


def effective_routes(cfg: SlaveConfig | MasterConfig) -> tuple[RouteConfig, ...]:
    """The routes in force: the implicit ones (listed first, as status shows them), then the
    file's."""
    return (*implicit_routes(cfg), *cfg.routes)


def route_map(cfg: SlaveConfig | MasterConfig) -> RouteMap:
    """The routing the daemon runs with: every face's explicit and implicit routes."""
    return RouteMap(effective_routes(cfg))


def routes_status(routes: RouteMap) -> list[dict]:
    """The routes as `mbgw status` lists them (both modes)."""
    return [{"face": r.face or "tcp", "units": number_list_text(r.units), "target": r.target,
             "rewrite": f"address {r.address}" if r.address is not None
             else f"offset {r.offset:+d}" if r.offset else "",
             "implicit": r.implicit} for r in routes.routes]


def has_serial_line(cfg: SlaveConfig | MasterConfig) -> bool:
    """Line serial runs: the file has [serial] (only a slave-mode file may leave it out)."""
    return not isinstance(cfg, SlaveConfig) or cfg.serial_line


def daemon_lines(cfg: SlaveConfig | MasterConfig, mode: str) -> tuple[LineConfig, ...]:
    """Every line the daemon runs: line serial (in the daemon's mode), unless [serial] is
    left out, then cfg.lines."""
    if not has_serial_line(cfg):
        return cfg.lines
    return (LineConfig(PRIMARY_LINE, cfg.serial, mode=mode), *cfg.lines)


def config_problems(cfg: SlaveConfig | MasterConfig, mode: str) -> list[str]:
    """What check-config refuses in a daemon's lines and routes: line serial (with the
    daemon's mode) and cfg.lines, the implicit routes beside the explicit ones."""
    lines = daemon_lines(cfg, mode)
    problems = _without_serial_problems(cfg) if isinstance(cfg, SlaveConfig) \
        and not cfg.serial_line else []
    problems += route_problems(lines, effective_routes(cfg))
    problems += device_problems(lines, effective_routes(cfg), cfg.devices)
    problems += [f"{r.label}.table: the table is off (table.enabled = false)"
                 for r in cfg.routes if r.table and not cfg.table_on]
    if not cfg.upstream_tls.enabled:
        problems += [f"{r.label}.tls: needs tls.client-cert, tls.client-key and "
                     f"tls.server-ca" for r in cfg.routes if r.tls]
    if mode == "master" and any(r.face == TCP_FACE for r in cfg.routes):
        problems += _tcp_face_problems(cfg)
    return problems


def _without_serial_problems(cfg: SlaveConfig) -> list[str]:
    """[serial] left out: nothing may address line serial, and without it no implicit route
    reaches a line, so the file's [[route]]s must."""
    problems = []
    if not cfg.routes:
        problems.append("serial.device: missing, so line serial does not run and no unit "
                        "reaches a line: give [serial] or [[route]] tables to the [[line]]s "
                        "(e.g. units = \"1-247\", line = \"NAME\")")
    if cfg.slaveid:
        problems.append(f"net.slaveid {cfg.slaveid}: the address on line serial, and "
                        f"[serial] is left out: give a [[route]] address instead")
    problems += [f"scenario {sc.name}: a serial scenario runs on line serial, and [serial] "
                 f"is left out" for sc in cfg.scenarios if sc.kind == "serial"]
    return problems


def _tcp_face_problems(cfg: SlaveConfig | MasterConfig) -> list[str]:
    """A master-mode daemon's Modbus TCP face listens on mdbport and, with TLS, tls.port:
    neither may be the table server's."""
    first = next(r for r in cfg.routes if r.face == TCP_FACE).label
    if not cfg.table.enabled:
        return []
    if cfg.mdbport == cfg.table.port:
        return [f"net.mdbport {cfg.mdbport}: {first} makes it the Modbus TCP face's port, "
                f"and the table's server listens on it (table.port)"]
    if cfg.tls.enabled:
        return [f"tls.port {cfg.tls.port}: {first} makes the Modbus TCP face listen on it, "
                f"and the table's server does too (table.enabled): route the table from "
                f"the face (table = true) instead, or leave [tls] out"]
    return []
