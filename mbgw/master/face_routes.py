"""What a serial face (a line in master mode) does with each serial address: its settings, and
the hop each address takes to its target, worked out once per configuration so that the
request path is one list index.

A face with routes of its own (`[[route]] from = NAME`) routes by them only: to a line in
slave mode (an Exchange handed to that line's thread), to the exchange table, to a remote
Modbus TCP server.  Line `serial` without routes of its own keeps master mode's routing: the
`slaveid` table to servers on `[net] mdbport`, and `table-address` to the table.  An address
no hop takes is never answered: another slave on the bus may own it."""
from dataclasses import dataclass
from typing import Callable

from mbgw.config.lines import PRIMARY_LINE, LineConfig, RouteConfig
from mbgw.config.model import Demotion, SerialConfig, UpstreamTlsConfig
from mbgw.config.route_plan import RouteMap
from mbgw.config.slaveid import SlaveIdTable

SERVER, TABLE, LINE = "server", "table", "line"
GATEWAY = "gateway"      # general.gateway-unit: the table's identity functions only


class Hop:
    """Where one serial address goes: kind, and for a server its host, port and unit id, for
    a line its name, the address there and the longest its answer may take."""
    __slots__ = ("kind", "host", "port", "unit", "line", "limit_ns", "pool", "upstream",
                 "cache")

    def __init__(self, kind: str, host: str = "", port: int = 0, unit: int = 0,
                 line: str = "", limit_ns: int = 0, pool=None, cache=None) -> None:
        self.kind = kind
        self.host = host
        self.port = port
        self.unit = unit              # the unit id (server) or serial address (line) there
        self.line = line
        self.limit_ns = limit_ns
        self.pool = pool              # the UpstreamPool for the server's port
        self.upstream = (host, unit)  # the device statistics' upstream (a server's)
        self.cache = cache            # a line's: the route's cache (Exchange.cache)

    @property
    def label(self) -> str:
        """The target as the trace shows it."""
        if self.kind == LINE:
            return f"line {self.line}"
        if self.kind == GATEWAY:
            return "gateway"
        return "table" if self.kind == TABLE else self.pool.server(self.host)


@dataclass(frozen=True)
class FaceSettings:
    """One serial face's settings: its line's, and the daemon's it shares."""
    name: str
    serial: SerialConfig
    tcpto_ms: int
    mdbport: int
    exception: bool
    max_connections: int
    demotion: Demotion
    upstream_tls: UpstreamTlsConfig
    slaveid: SlaveIdTable | None       # the routing of line serial without routes of its own
    routes: tuple[RouteConfig, ...]    # the face's own routes
    table_address: int                 # the table's serial address (line serial's); 0: none
    table_functions: tuple[int, ...]   # what the table's serial slave answers
    line_limits_ms: tuple[tuple[str, int], ...]   # (target line, longest its answer takes)
    gateway_unit: int = 0              # general.gateway-unit's serial address; 0: none

    @property
    def tcpto_ns(self) -> int:
        return self.tcpto_ms * 1_000_000

    @property
    def longest_wait_ms(self) -> int:
        """The longest a request waits for its target."""
        return max([self.tcpto_ms, *(ms for _, ms in self.line_limits_ms)])

    @property
    def owns_table_flags(self) -> bool:
        """Line serial's face sets the table's FC 7 line-down and device-down bits."""
        return self.name == PRIMARY_LINE


def face_settings(cfg, line: LineConfig | None, routes: RouteMap) -> FaceSettings:
    """The settings of the face of line (None: line serial, `[serial]` in master mode) in a
    daemon with the settings cfg (MasterConfig or SlaveConfig) and the routes."""
    name = line.name if line is not None else PRIMARY_LINE
    own = tuple(r for r in routes.routes if r.face == name and not r.implicit)
    slaveid = getattr(cfg, "slaveid", None) if name == PRIMARY_LINE and not own else None
    if not isinstance(slaveid, SlaveIdTable):
        slaveid = None
    table = cfg.table
    # the table's address stays line serial's route to the table beside routes of its own,
    # unless one of them goes to the table (config.route_plan.implicit_routes)
    table_address = table.address if (name == PRIMARY_LINE and table.enabled
                                      and not any(r.table for r in own)) else 0
    return FaceSettings(
        name=name, serial=line.serial if line is not None else cfg.serial,
        tcpto_ms=cfg.tcpto_ms, mdbport=cfg.mdbport, exception=cfg.exception,
        max_connections=cfg.max_connections,
        demotion=line.demotion if line is not None else cfg.demotion,
        upstream_tls=cfg.upstream_tls, slaveid=slaveid, routes=own,
        table_address=table_address,
        table_functions=table.serial_functions or table.functions,
        line_limits_ms=tuple((r.line, _line_limit_ms(cfg, r.line)) for r in own
                             if r.line is not None),
        gateway_unit=cfg.gateway_unit)


def _line_limit_ms(cfg, name: str) -> int:
    """A safety bound on a target line's answer (it always answers): every try of the
    request on the line, and tcpto for its queue."""
    if name == PRIMARY_LINE:
        stout_ms, retries = cfg.serial.stout_ms, getattr(cfg, "retries", 0)
    else:
        line = next((x for x in cfg.lines if x.name == name), None)
        stout_ms, retries = (line.serial.stout_ms, line.retries) if line else (0, 0)
    return cfg.tcpto_ms + stout_ms * (retries + 1)


def build_hops(face: FaceSettings, pool_for: Callable[[int], object],
               table_on: bool) -> list[Hop | None]:
    """Each serial address's hop (index 0, the broadcast address, is None).  pool_for(port):
    the upstream pool for servers on port; table_on: the face has the exchange table (the
    gateway unit answers from it too)."""
    hops: list[Hop | None] = [None] * 256
    table = Hop(TABLE) if table_on else None
    limits = dict(face.line_limits_ms)
    for route in face.routes:
        for address in route.units:
            unit = route.rewrite(address)
            if route.line is not None:
                hops[address] = Hop(LINE, unit=unit, line=route.line,
                                    limit_ns=limits[route.line] * 1_000_000,
                                    cache=route.cache)
            elif route.table:
                hops[address] = table
            elif route.server is not None:
                host, port = route.server
                hops[address] = Hop(SERVER, host, port, unit, pool=pool_for(port))
    if face.slaveid is not None:
        for address in range(1, 256):
            found = face.slaveid.route(address)
            if found is not None:
                hops[address] = Hop(SERVER, found[0], face.mdbport, found[1],
                                    pool=pool_for(face.mdbport))
    if face.table_address and table is not None:
        hops[face.table_address] = table
    if face.gateway_unit and table_on:
        hops[face.gateway_unit] = Hop(GATEWAY)
    hops[0] = None
    return hops


def ports(face: FaceSettings) -> set[int]:
    """The servers' ports the face reaches."""
    found = {r.server[1] for r in face.routes if r.server is not None}
    if face.slaveid is not None:
        found.add(face.mdbport)
    return found
