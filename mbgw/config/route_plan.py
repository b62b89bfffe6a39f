"""The routes in force, compiled: each face's explicit routes beside the implicit ones that
keep today's routing (`implicit_routes`), and the lines a daemon runs, line serial among
them unless `[serial]` is left out."""
import ipaddress

from mbgw.config.lines import PRIMARY_LINE, TCP_FACE, LineConfig, RouteConfig
from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.config.number_list import number_list_text


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
