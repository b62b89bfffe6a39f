"""The Modbus TCP face's routes at run time: for each unit id, the hop its request takes.

Without a `[[route]]` for the TCP face, every hop is today's: DIRECT (line `serial`, the unit
or `slaveid` as the serial address) or TO_TABLE (`[table] units`, or every unit with direct
messaging off).  A route to line `serial` with a rewrite is a hop of kind SERIAL; one to any
other line or to a remote server is ELSEWHERE: an Exchange submitted to that target's Inbox.
A unit no route takes has no hop (None).
"""
from mbgw.config.lines import PRIMARY_LINE, TCP_FACE, RouteConfig
from mbgw.config.model import SlaveConfig
from mbgw.config.route_plan import RouteMap, route_map
from mbgw.routing.queue import Inbox

SERIAL = "serial"        # line serial, owned by the TCP face's own line thread
TABLE = "table"
ELSEWHERE = "elsewhere"  # another line, a remote server: through its inbox
GATEWAY = "gateway"      # general.gateway-unit: the table's identity functions only


class Hop:
    """Where one unit's request goes from the TCP face, and the unit it becomes there."""
    __slots__ = ("kind", "offset", "address", "inbox", "line", "cache")

    def __init__(self, kind: str, route: RouteConfig | None = None,
                 inbox: Inbox | None = None) -> None:
        self.kind = kind
        self.offset = route.offset if route is not None else 0
        self.address = route.address if route is not None else None
        self.inbox = inbox
        self.cache = route.cache if route is not None else None   # None: the line's
        # the line it reaches (None: the table or a server), as the trace names it
        self.line = PRIMARY_LINE if kind == SERIAL else route.line if route is not None \
            else None

    def rewrite(self, unit: int) -> int:
        return self.address if self.address is not None else unit + self.offset


DIRECT = Hop(SERIAL)     # today's routing to line serial
TO_TABLE = Hop(TABLE)    # today's routing to the table
TO_GATEWAY = Hop(GATEWAY)


def effective_routes(cfg: SlaveConfig) -> RouteMap:
    """The routes in force: the file's, and today's routing as implicit routes where the
    file has none for it (config.route_plan.route_map)."""
    return route_map(cfg)


def face_hops(routes: RouteMap, inboxes: dict[str, Inbox], table_on: bool) -> list[Hop | None]:
    """The TCP face's 256 hops by unit.  inboxes: the targets' by name (a line's name, a
    server's target label); a route to a target without one, or to the table while it is
    off, takes nothing.  table_on: the table is there to answer (the gateway unit answers
    from it even while it is off)."""
    hops: list[Hop | None] = []
    made: dict[int, Hop | None] = {}
    for route in routes.units(TCP_FACE):
        if route is None:
            hops.append(None)
            continue
        if id(route) not in made:
            made[id(route)] = _hop(route, inboxes, table_on)
        hops.append(made[id(route)])
    return hops


def _hop(route: RouteConfig, inboxes: dict[str, Inbox], table_on: bool) -> Hop | None:
    if route.gateway:
        return TO_GATEWAY if table_on else None
    if route.table:
        if not table_on:
            return None
        same = route.implicit or (route.offset == 0 and route.address is None)
        return TO_TABLE if same else Hop(TABLE, route)
    if route.line == PRIMARY_LINE:
        return DIRECT if route.implicit else Hop(SERIAL, route)
    inbox = inboxes.get(route.line if route.line is not None else route.target)
    return Hop(ELSEWHERE, route, inbox) if inbox is not None else None


def is_today(hops: list[Hop | None]) -> bool:
    """Every unit routed as without routes (the C shortcut may take the line's requests)."""
    return all(h is DIRECT or h is TO_TABLE for h in hops)


def answered_off_the_line(hops: list[Hop | None]) -> bool:
    """Some unit is answered elsewhere than on line serial (the table, another target): the
    table reader then serves the clients while line serial is in a transaction."""
    return any(h is not None and h.kind is not SERIAL for h in hops)
