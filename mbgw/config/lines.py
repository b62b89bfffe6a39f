"""Lines, faces, routes and targets: the settings of a daemon with more than one line.

A *face* is where requests come in: the Modbus TCP listeners (`TCP_FACE`) or a line in master
mode (an outside master on it: its serial-slave face).  A *target* is where a request is
answered: a line in slave mode (mbgw is the master on it), the exchange table, or a remote
Modbus TCP server.  A *route* takes a face's units (serial addresses, on a serial face) to a
target, each rewritten on the way (an offset, or one fixed address).

`[serial]` is the first line, named `serial`; `[[line]]` tables add more, `[[route]]` tables
the routes.  Without a route for a face, the face keeps today's routing (`implicit` routes).

Compiling the routes in force is `route_plan`'s, checking lines, routes and devices
together `route_checks`', reading the tables `line_file`'s.
"""
import re
from dataclasses import dataclass, field

from mbgw.config.cache import CacheRule, RouteCache
from mbgw.config.model import DEFAULT_TURNAROUND_MS, Demotion, SerialConfig
from mbgw.errors import ConfigError

PRIMARY_LINE = "serial"            # [serial]'s name; reserved for it
TCP_FACE = ""                      # the face of the Modbus TCP listeners (plain and TLS)
LINE_MODES = ("slave", "master")   # slave: mbgw masters the line; master: a master is on it
LINE_KINDS = (*LINE_MODES, "monitor")   # a [[line]]'s; monitor: mbgw only listens
NAME_PATTERN = re.compile(r"[a-z0-9][a-z0-9-]{0,31}")
MAX_LINES = 32
MAX_ROUTES = 256
MAX_SERVER_UNIT = 255


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
