"""What check-config refuses in a daemon's lines, routes and [[device]] tables taken
together, each problem naming its key."""
from mbgw.config.lines import (
    MAX_SERVER_UNIT,
    TCP_FACE,
    DeviceConfig,
    LineConfig,
    RouteConfig,
)
from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.config.route_plan import daemon_lines, effective_routes
from mbgw.errors import ConfigError
from mbgw.protocol import pdu


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
