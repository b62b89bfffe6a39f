"""Validated settings: the serial line's, the table's, TLS, web, slave and master mode's
(transparent mode's are in config.transparent).  Options keep the ACKSYS names and units
(ms); every default and bound is stated once, here or in the module of its settings."""
import ipaddress
import math
import os
import re
import stat
from dataclasses import dataclass, field

from mbgw.config.cache import CacheRule
from mbgw.config.firewall import FirewallConfig
from mbgw.config.mqtt import MqttConfig
from mbgw.config.scenario import check_scenarios
from mbgw.config.slaveid import SlaveIdTable
from mbgw.errors import ConfigError

# Rates libmodbus 3.1.6 sets itself; it silently turns any other rate into 9600.
LIBMODBUS_BAUDRATES = (110, 300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200,
                       230400, 460800, 500000, 576000, 921600, 1000000, 1152000, 1500000,
                       2500000, 3000000, 3500000, 4000000)
BAUDRATE_RANGE = (50, 4000000)   # others than libmodbus's are set through termios2/BOTHER
FORMAT_PATTERN = re.compile(r"^([78])([neoms])([12])$")
PROTOCOLS = ("rtu", "ascii")
INTERFACES = ("rs232", "rs485", "rs422")
DEFAULT_ASCII_TIMEOUT_MS = 1000   # Serial Line V1.02 2.5.2.1: inter-character time-out
MAX_AUTHIP = 8
STOUT_RANGE = (1, 65535)
DEFAULT_STOUT_MS = 600
# the other bounds of the options (the click options read these)
RTSDELAY_RANGE = (0, 255)
# RS-232 control lines (the guide's `set serial dtr|rts|cts|xonxoff`); "modem" RTS is raised
# for each frame, rtsdelays around it: a radio modem's push-to-talk.
DTR_MODES = ("high", "low")
RTS_MODES = ("high", "low", "flow", "modem")
CTS_MODES = ("ignore", "flow")
XONXOFF_MODES = ("ignore", "use")
SILENCE_RANGE = (0, 65535)
INTERFRAME_SILENCE_RANGE = (0, 65535)  # ms beyond t3.5 (VPGate's "Interframe silence")
ASCII_TIMEOUT_RANGE = (1, 65535)
SLAVEID_RANGE = (0, 247)
GATEWAY_UNIT_RANGE = (0, 255)   # [general] gateway-unit; 0: off
PORT_RANGE = (1, 65535)
MDBPORT_RANGE = (0, 65535)      # slave mode: 0 is no plain Modbus TCP (TLS only)
MAX_CONNECTIONS_RANGE = (1, 1000)
MAX_CONNECTIONS_PER_IP_RANGE = (0, 1000)
RETRIES_RANGE = (0, 65535)     # as VPGate allows
# After a timeout, an address's next request waits until its late reply has come or the line
# has been quiet this long past the timeout (ms; 0: no wait).  Default: stout.
LATE_WINDOW_RANGE = (0, 65535)
TURNAROUND_RANGE = (0, 65535)
DEFAULT_MDBPORT = 502
DEFAULT_MAX_CONNECTIONS = 5
DEFAULT_TURNAROUND_MS = 100    # Serial Line V1.02 2.4.1: "typically 100 to 200 ms"
FAST_LINE_BAUD = 19200         # above it, t3.5 is the fixed 1.75 ms (Serial Line V1.02 2.5.1.1)
FAST_LINE_T35_US = 1750
# A client that sent a request or got a reply within this is polling: no newcomer closes it.
ACTIVE_WINDOW_S = 60
# Demotion: a serial address down after this many failures in a row (0: never) has its
# requests refused at once, but for one probe per interval (ms, as stout and tcpto), which
# doubles while the address stays silent up to PROBE_BACKOFF_MAX_MS (or the interval if longer).
DOWN_AFTER_RANGE = (0, 100)
DEFAULT_DOWN_AFTER = 3
PROBE_INTERVAL_RANGE = (100, 65535)
DEFAULT_PROBE_INTERVAL_MS = 5000
PROBE_BACKOFF_MAX_MS = 60000
# [[device]] pause: the line quiet at least this long before each frame to the unit (ms)
PAUSE_RANGE = (0, 65535)
# A request (a Modbus request, a TLS handshake, an HTTP request's headers) must be whole this
# long after its first byte, or its connection is closed ([net] request-timeout, ms).
REQUEST_TIMEOUT_RANGE = (100, 60000)
DEFAULT_REQUEST_TIMEOUT_MS = 2000


def check_range(name: str, value: int, bounds: tuple[int, int],
                key: str | None = None) -> None:
    """Raises ConfigError "NAME VALUE: out of range LOW..HIGH" when value is outside bounds;
    key: the setting the error blames, when the caller knows it."""
    low, high = bounds
    if not low <= value <= high:
        raise ConfigError(f"{name} {value}: out of range {low}..{high}", key=key)


@dataclass(frozen=True)
class LineFormat:
    data_bits: int = 8
    parity: str = "n"
    stop_bits: int = 1

    @classmethod
    def parse(cls, text: str) -> "LineFormat":
        match = FORMAT_PATTERN.fullmatch(text.lower())
        if not match:
            raise ConfigError(f"format {text!r}: expected data bits (7 or 8), parity "
                              f"(n, e, o, m or s) and stop bits (1 or 2), e.g. 8n1")
        return cls(int(match[1]), match[2], int(match[3]))

    @property
    def char_bits(self) -> int:
        """Bits on the wire per character: start + data + parity + stop."""
        return 1 + self.data_bits + (0 if self.parity == "n" else 1) + self.stop_bits

    def __str__(self) -> str:
        return f"{self.data_bits}{self.parity}{self.stop_bits}"


INTERFACE_SYNONYMS = {"2wires": "rs485", "4wires": "rs422"}   # the guide: "synonyms"
INTERFACE_OPTIONS = {"rs485": ("echo", "noecho"), "rs422": ("master", "slave")}


@dataclass(frozen=True)
class Interface:
    """The electrical interface: rs232; rs422 (4wires) as a master, whose transmitter is always
    on, or a multidrop slave, whose transmitter is on only while it sends; rs485 (2wires) with
    or without its own echo."""
    kind: str = "rs232"
    echo: bool = False
    slave: bool = False

    @classmethod
    def parse(cls, text: str) -> "Interface":
        words = text.lower().split()
        if words:
            words[0] = INTERFACE_SYNONYMS.get(words[0], words[0])
        if not words or words[0] not in INTERFACES or len(words) > 2 or (
                len(words) == 2 and words[1] not in INTERFACE_OPTIONS.get(words[0], ())):
            raise ConfigError(f"interface {text!r}: expected rs232, rs422 (or 4wires) master "
                              f"or slave, rs485 (or 2wires) echo or noecho")
        option = words[1] if len(words) == 2 else ""
        return cls(words[0], option == "echo", option == "slave")

    @property
    def drives_rts(self) -> bool:
        """RTS switches the transmitter on for each frame (RS-485, an RS-422 slave)."""
        return self.kind == "rs485" or self.slave

    def __str__(self) -> str:
        if self.echo:
            return f"{self.kind} echo"
        return f"{self.kind} slave" if self.slave else self.kind


@dataclass(frozen=True)
class Demotion:
    """When a serial address is down, and how often it is probed meanwhile (both modes)."""
    down_after: int = DEFAULT_DOWN_AFTER
    probe_interval_ms: int = DEFAULT_PROBE_INTERVAL_MS

    def __post_init__(self) -> None:
        check_range("down-after", self.down_after, DOWN_AFTER_RANGE)
        check_range("probe-interval", self.probe_interval_ms, PROBE_INTERVAL_RANGE)


NO_DEVICE = ""    # the device of a [serial] left out (SlaveConfig.serial_line False)


@dataclass(frozen=True)
class SerialConfig:
    device: str
    baudrate: int = 9600
    format: LineFormat = field(default_factory=LineFormat)
    stout_ms: int = DEFAULT_STOUT_MS
    protocol: str = "rtu"
    silence_ms: int = 0            # 0: the standard t3.5
    nocheck: bool = False
    interface: Interface = field(default_factory=Interface)
    rtsdelays: tuple[int, int] = (0, 0)
    ascii_timeout_ms: int = DEFAULT_ASCII_TIMEOUT_MS
    dtr: str = "high"
    rts: str = "high"
    cts: str = "ignore"
    xonxoff: str = "ignore"
    interframe_ms: int = 0         # VPGate: the line quiet this much beyond t3.5 before we send

    def __post_init__(self) -> None:
        check_range("interframe-silence", self.interframe_ms, INTERFRAME_SILENCE_RANGE)
        check_range("baudrate", self.baudrate, BAUDRATE_RANGE)
        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"protocol {self.protocol!r}: expected rtu or ascii")
        for name, value, modes in (("dtr", self.dtr, DTR_MODES), ("rts", self.rts, RTS_MODES),
                                   ("cts", self.cts, CTS_MODES),
                                   ("xonxoff", self.xonxoff, XONXOFF_MODES)):
            if value not in modes:
                raise ConfigError(f"{name} {value!r}: expected {' or '.join(modes)}")
        if (self.rts == "flow") != (self.cts == "flow"):
            raise ConfigError(f"rts {self.rts} with cts {self.cts}: RTS/CTS flow control is "
                              f"both or neither (Linux's CRTSCTS): set rts flow and cts flow")
        if self.interface.drives_rts and self.rts != "high":
            raise ConfigError(f"rts {self.rts}: interface {self.interface} drives its "
                              f"transmitter with RTS; rts applies to rs232 and rs422 master")

    @property
    def wiring(self) -> str:
        """The interface and the control lines that differ from their defaults, as logs and
        status show them: "rs232, rts modem, xonxoff use"."""
        changed = [f"{name} {value}" for name, value, default in (
            ("dtr", self.dtr, "high"), ("rts", self.rts, "high"), ("cts", self.cts, "ignore"),
            ("xonxoff", self.xonxoff, "ignore")) if value != default]
        return ", ".join((str(self.interface), *changed))

    @property
    def rts_ptt(self) -> bool:
        """mbgw raises RTS for each frame itself: RS-232 push-to-talk (rts modem)."""
        return self.rts == "modem"

    @property
    def libmodbus_baudrate(self) -> bool:
        """libmodbus can set this rate itself (others go through termios2)."""
        return self.baudrate in LIBMODBUS_BAUDRATES

    @property
    def char_ns(self) -> int:
        return self.format.char_bits * 1_000_000_000 // self.baudrate

    @property
    def end_of_frame_us(self) -> int:
        """The silence that ends an RTU frame: --silence, else t3.5."""
        return self.silence_ms * 1000 or self.t35_us

    @property
    def t35_us(self) -> int:
        """Inter-frame silence (t3.5)."""
        if self.baudrate > FAST_LINE_BAUD:
            return FAST_LINE_T35_US
        return math.ceil(3.5 * self.format.char_bits * 1_000_000 / self.baudrate)


# The guide's `set location`: a description of the device, shown in status, the console and
# the table's configuration zone.
DEFAULT_LOCATION = "Unknown location"
LOCATION_MAX = 30                              # "30 bytes max"


def parse_location(text: str) -> str:
    if len(text) > LOCATION_MAX:
        raise ConfigError(f"location {text!r}: at most {LOCATION_MAX} characters, got "
                          f"{len(text)}")
    if not (text.isascii() and text.isprintable()):
        raise ConfigError(f"location {text!r}: printable ASCII only (it is written in the "
                          f"table's configuration zone)")
    return text


# The exchange table (mbgw/table): VPGate's register memory, served to both sides.
TABLE_FUNCTIONS = (1, 2, 3, 4, 5, 6, 7, 15, 16, 23)
DEFAULT_TABLE_UNITS = tuple(range(247, 255))   # slave mode, direct messaging on
TABLE_ADDRESS_RANGE = (0, 247)                 # master mode; 0: the line has no table slave
DEFAULT_TABLE_PORT = 502                       # master mode: TCP clients reach the table here
DEFAULT_TABLE_MAX_CONNECTIONS = 32             # its clients at once (mbgw.table.server)
PERSIST_INTERVAL_RANGE = (1, 86400)            # s
DEFAULT_PERSIST_INTERVAL_S = 10
# table-persist lives in the service's state directory, nowhere else (a console admin must not
# choose where the daemon writes)
DEFAULT_STATE_DIRECTORY = "/var/lib/mbgw"


def state_directory() -> str:
    """systemd's StateDirectory when it set one ($STATE_DIRECTORY), else /var/lib/mbgw."""
    return (os.environ.get("STATE_DIRECTORY") or DEFAULT_STATE_DIRECTORY).split(":")[0]


def check_persist_path(text: str) -> str:
    """table-persist's file: an absolute path, a regular file if it exists (never a link, a
    directory, a device or a FIFO), inside the state directory (links and .. resolved).
    Raises ConfigError naming the key and why."""
    if not text.strip():
        raise ConfigError("table-persist: empty; expected a file path")
    directory = os.path.realpath(state_directory())
    if not os.path.isabs(text):
        raise ConfigError(f"table-persist {text!r}: not an absolute path; the file must be "
                          f"in {directory}")
    try:
        mode = os.lstat(text).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as err:
        raise ConfigError(f"table-persist {text!r}: {err.strerror}") from None
    if mode is not None and stat.S_ISDIR(mode):
        raise ConfigError(f"table-persist {text!r}: is a directory, not a regular file")
    if mode is not None and not stat.S_ISREG(mode):
        raise ConfigError(f"table-persist {text!r}: not a regular file (a link, a device or a "
                          f"FIFO is never the table's file)")
    where = os.path.join(os.path.realpath(os.path.dirname(text)), os.path.basename(text))
    if os.path.commonpath([where, directory]) != directory or where == directory:
        raise ConfigError(f"table-persist {text!r}: outside the state directory {directory} "
                          f"($STATE_DIRECTORY): mbgw keeps the table nowhere else")
    return text


def table_address_conflict(address: int, slaveid: SlaveIdTable) -> str | None:
    """Master mode: why the table's serial address cannot be `address` with this slaveid
    table (a range routing it to a TCP server), or None."""
    if address == 0:
        return None
    for r in slaveid.ranges:
        if r.first <= address <= r.last:
            return (f"serial address {address} is in the slaveid range {r.first}..{r.last} "
                    f"({r.line()}): one address cannot be both the table and a TCP server")
    return None


@dataclass(frozen=True)
class TableConfig:
    """The exchange table: whether it is on, who reaches it, what it answers, where it is kept."""
    enabled: bool = False
    direct: bool = True            # slave mode: units outside `units` go to the line
    units: tuple[int, ...] = DEFAULT_TABLE_UNITS
    functions: tuple[int, ...] = TABLE_FUNCTIONS
    serial_functions: tuple[int, ...] | None = None   # master mode's serial slave; None: functions
    address: int = 0               # master mode: the serial address mbgw answers as (0: none)
    port: int = DEFAULT_TABLE_PORT
    max_connections: int = DEFAULT_TABLE_MAX_CONNECTIONS   # master mode's table-port clients
    persist: str | None = None     # file keeping the outputs and the free zone; None: not kept
    persist_interval_s: int = DEFAULT_PERSIST_INTERVAL_S

    def __post_init__(self) -> None:
        for unit in self.units:
            if not 1 <= unit <= 255:
                raise ConfigError(f"table-units {unit}: out of range 1..255 (unit 0 is the "
                                  f"broadcast)")
        for name, functions in (("table-functions", self.functions),
                                ("table-serial-functions", self.serial_functions or ())):
            for function in functions:
                if function not in TABLE_FUNCTIONS:
                    raise ConfigError(f"{name} {function}: the table answers only "
                                      f"{', '.join(map(str, TABLE_FUNCTIONS))}")
        check_range("table-address", self.address, TABLE_ADDRESS_RANGE)
        check_range("table-port", self.port, PORT_RANGE)
        check_range("table-max-connections", self.max_connections, MAX_CONNECTIONS_RANGE)
        check_range("table-persist-interval", self.persist_interval_s, PERSIST_INTERVAL_RANGE)


TCPTO_RANGE = (1, 65535)
DEFAULT_TCPTO_MS = 800          # ACKSYS "set net tcpto" default


# Modbus/TCP Security: TLS on its own port beside (or, slave mode's mdbport 0, instead of)
# plain Modbus TCP; the client's role is in its certificate's extension ROLE_OID.
DEFAULT_TLS_PORT = 802
ROLE_OID = "1.3.6.1.4.1.50316.802.1"


@dataclass(frozen=True)
class TlsConfig:
    """TLS for the Modbus TCP servers: on when a certificate is given."""
    port: int = DEFAULT_TLS_PORT
    cert: str | None = None        # the server's certificate (PEM)
    key: str | None = None         # its private key (PEM)
    ca: str | None = None          # the CA that client certificates must chain to (PEM)
    require_role: bool = True      # a client certificate without a role may do nothing
    crl: str | None = None         # revoked client certificates (PEM CRL)
    # (path, mtime_ns, size) of each file when read, so that a renewed file is a change that
    # a reload applies; the settings never name it
    files: tuple = ()

    def __post_init__(self) -> None:
        check_range("tls.port", self.port, PORT_RANGE)
        if self.cert is not None:
            missing = [name for name in ("key", "ca") if getattr(self, name) is None]
            if missing:
                raise ConfigError(f"tls-cert given without "
                                  f"{' and '.join('tls-' + m for m in missing)}: TLS needs the "
                                  f"server's key and the CA of the clients' certificates")
        elif self.key is not None or self.ca is not None or self.crl is not None:
            raise ConfigError("tls-key/tls-ca/tls-crl given without tls-cert: TLS is on only "
                              "with a server certificate")

    @property
    def enabled(self) -> bool:
        return self.cert is not None

    @property
    def roles_required(self) -> bool:
        """Whether a TLS client whose certificate has no role is refused every request."""
        return self.enabled and self.require_role


# The web console (mbgw/web): off until [web] listen is given, and then only with an admin
# password; the passwords are salted scrypt hashes that `mbgw config password` writes.
WEB_EXAMPLE_LISTEN = "127.0.0.1:8080"      # what the factory file shows, commented out


@dataclass(frozen=True)
class WebConfig:
    """The web console: where it listens, HTTPS, the two roles' password hashes."""
    listen: str | None = None          # ADDR:PORT; None: off
    cert: str | None = None            # HTTPS: the certificate (PEM) ...
    key: str | None = None             # ... and its private key (PEM)
    admin_password: str | None = None  # scrypt$N$r$p$salt$hash
    user_password: str | None = None
    https_only: bool = False           # plain HTTP redirected to HTTPS, HSTS set
    request_timeout_ms: int = DEFAULT_REQUEST_TIMEOUT_MS   # [net] request-timeout's

    def __post_init__(self) -> None:
        if (self.cert is None) != (self.key is None):
            raise ConfigError("web-cert and web-key go together: HTTPS needs the certificate "
                              "and its private key")
        if self.https_only and self.cert is None:
            raise ConfigError("web.https-only needs HTTPS: give web.cert and web.key")
        if self.listen is not None and self.admin_password is None:
            raise ConfigError("no admin password set: the web console needs one (mbgw config "
                              "password admin)")

    @property
    def https(self) -> bool:
        return self.cert is not None


@dataclass(frozen=True)
class UpstreamTlsConfig:
    """TLS to the remote Modbus TCP servers (master mode's `tls` slaveid ranges, `tls` TCP
    scenarios): mbgw's client certificate and key, the CA the servers' certificates must chain
    to, and the servers' TLS port (master mode)."""
    client_cert: str | None = None
    client_key: str | None = None
    server_ca: str | None = None
    server_port: int = DEFAULT_TLS_PORT
    files: tuple = ()              # (path, mtime_ns, size): a renewed file is a change

    def __post_init__(self) -> None:
        check_range("tls.server-port", self.server_port, PORT_RANGE)
        given = [n for n in ("client-cert", "client-key", "server-ca")
                 if getattr(self, n.replace("-", "_")) is not None]
        if given and len(given) < 3:
            missing = [f"tls-{n}" for n in ("client-cert", "client-key", "server-ca")
                       if n not in given]
            raise ConfigError(f"tls-{given[0]} given without {' and '.join(missing)}: TLS to "
                              f"servers needs mbgw's certificate, its key and the servers' CA")

    @property
    def enabled(self) -> bool:
        return self.client_cert is not None



def check_upstream_tls(upstream: UpstreamTlsConfig, scenarios, slaveid=None) -> None:
    """A `tls` slaveid range or TCP scenario needs the client certificate."""
    if upstream.enabled:
        return
    for sc in scenarios:
        if getattr(sc, "tls", False):
            raise ConfigError(f"scenario {sc.name}: tls needs tls-client-cert, tls-client-key "
                              f"and tls-server-ca")
    for r in getattr(slaveid, "ranges", ()):
        if r.tls:
            raise ConfigError(f"slaveid {r.line()!r}: tls needs tls-client-cert, "
                              f"tls-client-key and tls-server-ca")


@dataclass(frozen=True)
class SlaveConfig:
    """Slave mode: slaves on the serial line, Modbus TCP clients on the network."""
    serial: SerialConfig
    slaveid: int = 0
    exception: bool = False
    authip: tuple = ()
    mdbport: int = DEFAULT_MDBPORT
    udp_port: int = 0              # [net] udp-port: the Modbus/UDP face; 0: off
    rtu_port: int = 0              # [net] rtu-port: the RTU-over-TCP face; 0: off
    bind: str | None = None
    max_connections: int = DEFAULT_MAX_CONNECTIONS
    max_connections_per_ip: int = 0    # 0: no limit per client address
    retries: int = 0
    turnaround_ms: int = DEFAULT_TURNAROUND_MS
    late_window_ms: int | None = None  # None: stout
    cache: CacheRule | None = None     # line serial's reads shared and kept; None: off
    control: str | None = None     # control socket path; None: the default one
    metrics: str | None = None     # ADDR:PORT for Prometheus, None: off
    demotion: Demotion = field(default_factory=Demotion)
    shortcut: bool = True          # an idle line's request goes on it from C (a hidden switch)
    table: TableConfig = field(default_factory=TableConfig)
    firewall: FirewallConfig | None = None   # [[rule]] tables; None: every request allowed
    tcpto_ms: int = DEFAULT_TCPTO_MS   # TCP scenarios: the time for a transaction with a server
    scenarios: tuple = ()          # ScenarioConfig (mbgw.config.scenario), [[scenario]]
    config_file: str | None = None  # the file the settings came from (scenario ... --save)
    tls: TlsConfig = field(default_factory=TlsConfig)
    upstream_tls: UpstreamTlsConfig = field(default_factory=UpstreamTlsConfig)
    web: WebConfig = field(default_factory=WebConfig)   # [web]: the web console
    mqtt: MqttConfig = field(default_factory=MqttConfig)   # [mqtt]: northbound MQTT
    request_timeout_ms: int = DEFAULT_REQUEST_TIMEOUT_MS   # [net] request-timeout
    location: str = DEFAULT_LOCATION   # [general] location, the guide's set location
    gateway_unit: int = 0          # [general] gateway-unit: every face's unit (serial
                                   # address) of the identity functions only (FC 8, 17,
                                   # 43/14); 0: none
    lines: tuple = ()              # LineConfig (mbgw.config.lines): [[line]], beside [serial]
    routes: tuple = ()             # RouteConfig (mbgw.config.lines): [[route]]
    monitors: tuple = ()           # MonitorMap (mbgw.config.monitor): [[monitor]]
    devices: tuple = ()            # DeviceConfig (mbgw.config.lines): [[device]]
    @property
    def serial_line(self) -> bool:
        """Line serial runs.  Not when the file leaves [serial] out, its [[line]]s defining
        the lines: `serial` then holds only the defaults the [[line]]s take."""
        return self.serial.device != NO_DEVICE

    def __post_init__(self) -> None:
        _check_scenarios(self.scenarios, "slave")
        check_upstream_tls(self.upstream_tls, self.scenarios)
        if self.mdbport == 0 and not self.tls.enabled:
            raise ConfigError("mdbport 0 turns plain Modbus TCP off: it needs TLS (--tls-cert)",
                              key="mdbport")
        check_range("tcpto", self.tcpto_ms, TCPTO_RANGE, key="tcpto")
        if len(self.authip) > MAX_AUTHIP:
            raise ConfigError(f"authip: at most {MAX_AUTHIP} addresses, got {len(self.authip)}",
                              key="authip")
        object.__setattr__(self, "authip", tuple(parse_ip("authip", a) for a in self.authip))
        if self.late_window_ms is not None:
            check_range("late-window", self.late_window_ms, LATE_WINDOW_RANGE, key="late-window")

    @property
    def late_window(self) -> int:
        """The late window in ms: late-window, else stout."""
        return self.serial.stout_ms if self.late_window_ms is None else self.late_window_ms

    @property
    def table_on(self) -> bool:
        """The exchange table runs: asked for, or a scenario or a monitor map needs it."""
        return self.table.enabled or bool(self.scenarios) or bool(self.monitors)


def _check_scenarios(scenarios, mode: str) -> None:
    problems = check_scenarios(scenarios, mode)
    if problems:
        raise ConfigError(problems[0])


def parse_ip(option: str, text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    try:
        # Peers are compared without their scope id (see mbgw.net.acl.AccessList.allows)
        address = ipaddress.ip_address(str(text).split("%", 1)[0])
    except ValueError:
        raise ConfigError(f"{option} {text!r}: not an IP address") from None
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped:
        return address.ipv4_mapped
    return address


@dataclass(frozen=True)
class MasterConfig:
    """Master mode: a Modbus master on the serial line, Modbus TCP servers on the network."""
    serial: SerialConfig
    slaveid: SlaveIdTable
    tcpto_ms: int = DEFAULT_TCPTO_MS
    mdbport: int = DEFAULT_MDBPORT  # the remote servers' port
    exception: bool = False
    max_connections: int = DEFAULT_MAX_CONNECTIONS
    control: str | None = None      # control socket path; None: the default one
    metrics: str | None = None      # ADDR:PORT for Prometheus, None: off
    demotion: Demotion = field(default_factory=Demotion)
    table: TableConfig = field(default_factory=TableConfig)
    upstream_tls: UpstreamTlsConfig = field(default_factory=UpstreamTlsConfig)
    firewall: FirewallConfig | None = None   # the table server's; None: all allowed
    scenarios: tuple = ()           # ScenarioConfig (mbgw.config.scenario): TCP ones only
    config_file: str | None = None  # the file the settings came from (scenario ... --save)
    tls: TlsConfig = field(default_factory=TlsConfig)    # on the table's server
    web: WebConfig = field(default_factory=WebConfig)   # [web]: the web console
    mqtt: MqttConfig = field(default_factory=MqttConfig)   # [mqtt]: northbound MQTT
    request_timeout_ms: int = DEFAULT_REQUEST_TIMEOUT_MS   # [net] request-timeout
    location: str = DEFAULT_LOCATION   # [general] location, the guide's set location
    gateway_unit: int = 0           # [general] gateway-unit, as SlaveConfig's
    authip: tuple = ()              # the table server's allowed clients; empty: anyone
    bind: str | None = None         # the table server's one address; None: every one
    udp_port: int = 0               # [net] udp-port: the TCP face's Modbus/UDP listener
    rtu_port: int = 0               # [net] rtu-port: the TCP face's RTU-over-TCP listener
    lines: tuple = ()               # LineConfig (mbgw.config.lines): [[line]], beside [serial]
    routes: tuple = ()              # RouteConfig (mbgw.config.lines): [[route]]
    monitors: tuple = ()            # MonitorMap (mbgw.config.monitor): [[monitor]]
    devices: tuple = ()             # DeviceConfig (mbgw.config.lines): [[device]]

    def __post_init__(self) -> None:
        _check_scenarios(self.scenarios, "master")
        if len(self.authip) > MAX_AUTHIP:
            raise ConfigError(f"authip: at most {MAX_AUTHIP} addresses, got {len(self.authip)}",
                              key="authip")
        object.__setattr__(self, "authip", tuple(parse_ip("authip", a) for a in self.authip))
        check_upstream_tls(self.upstream_tls, self.scenarios, self.slaveid)
        check_range("tcpto", self.tcpto_ms, TCPTO_RANGE, key="tcpto")
        if self.max_connections < 1:
            raise ConfigError(f"max-connections {self.max_connections}: at least 1",
                              key="max-connections")
        conflict = table_address_conflict(self.table.address, self.slaveid) \
            if self.table.enabled else None
        if conflict:
            raise ConfigError(f"table-address {self.table.address}: {conflict}",
                              key="table-address")

    @property
    def table_on(self) -> bool:
        """The exchange table runs: asked for, or a scenario or a monitor map needs it."""
        return self.table.enabled or bool(self.scenarios) or bool(self.monitors)

    @property
    def tcpto_ns(self) -> int:
        return self.tcpto_ms * 1_000_000
