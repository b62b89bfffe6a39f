"""Transparent mode's settings (VPGate 3.8, 6.5.2): raw frames between the line and the
table, how they are cut and where they are in it."""
import math
from dataclasses import dataclass, field

from mbgw.config.firewall import FirewallConfig
from mbgw.config.model import (
    DEFAULT_LOCATION,
    DEFAULT_MDBPORT,
    DEFAULT_REQUEST_TIMEOUT_MS,
    DEFAULT_TCPTO_MS,
    INTERFRAME_SILENCE_RANGE,
    MAX_AUTHIP,
    PORT_RANGE,
    SerialConfig,
    TableConfig,
    TlsConfig,
    WebConfig,
    check_range,
    parse_ip,
)
from mbgw.config.mqtt import MqttConfig
from mbgw.errors import ConfigError

EOF_CHARS = {"nul": b"\x00", "space": b" ", "lf": b"\n", "cr": b"\r", "crlf": b"\r\n",
             "lfcr": b"\n\r"}
EOF_KINDS = (*EOF_CHARS, "char", "length", "timeout")
EOF_CHAR_RANGE = (0, 255)
EOF_TIMEOUT_RANGE = (0, 65535)         # ms; 0: the serial line's end-of-frame silence
RX_ADDRESS_RANGE = (0, 2047)           # the inputs zone
TX_ADDRESS_RANGE = (2048, 4095)        # the outputs zone
FRAME_SIZE_RANGE = (1, 250)            # bytes, two to a register


@dataclass(frozen=True)
class TransparentConfig:
    """How frames are cut on the line and where they are in the table."""
    eof: str = "cr"
    eof_char: int = 0x0D
    eof_timeout_ms: int = 0
    rx_address: int = 0
    rx_size: int = 250
    tx_address: int = 2048
    tx_size: int = 250
    crc: bool = False
    trigger: bool = False
    silence_ms: int = 0            # after a frame was received, before sending
    raw_port: int | None = None    # one TCP client's raw byte stream to the line; None: off

    def __post_init__(self) -> None:
        if self.eof not in EOF_KINDS:
            raise ConfigError(f"eof {self.eof!r}: expected one of {', '.join(EOF_KINDS)}")
        check_range("eof-char", self.eof_char, EOF_CHAR_RANGE)
        check_range("eof-timeout", self.eof_timeout_ms, EOF_TIMEOUT_RANGE)
        check_range("rx-size", self.rx_size, FRAME_SIZE_RANGE)
        check_range("tx-size", self.tx_size, FRAME_SIZE_RANGE)
        check_range("transparent.silence", self.silence_ms, INTERFRAME_SILENCE_RANGE)
        for name, address, size, (low, high) in (
                ("rx-address", self.rx_address, self.rx_size, RX_ADDRESS_RANGE),
                ("tx-address", self.tx_address, self.tx_size, TX_ADDRESS_RANGE)):
            last = address + registers_of(size) - 1
            if not low <= address <= high or last > high:
                raise ConfigError(f"{name} {address}: the area (registers {address}..{last}) "
                                  f"must lie in {low}..{high}")
        if self.raw_port is not None and not PORT_RANGE[0] <= self.raw_port <= PORT_RANGE[1]:
            raise ConfigError(f"raw-port {self.raw_port}: out of range {PORT_RANGE[0]}.."
                              f"{PORT_RANGE[1]}")

    @property
    def end(self) -> bytes | None:
        """The characters that end a frame, None when a frame ends otherwise."""
        if self.eof == "char":
            return bytes([self.eof_char])
        return EOF_CHARS.get(self.eof)

    def eof_timeout_for(self, serial: SerialConfig) -> int:
        """eof-timeout in ms, the serial line's end-of-frame silence (at least 1 ms) for 0."""
        return self.eof_timeout_ms or max(1, math.ceil(serial.end_of_frame_us / 1000))


def registers_of(size: int) -> int:
    """The registers that hold size bytes, two to a register."""
    return (size + 1) // 2


@dataclass(frozen=True)
class TransparentModeConfig:
    """Transparent mode: raw frames on the serial line, the table served on mdbport."""
    serial: SerialConfig
    transparent: TransparentConfig = field(default_factory=TransparentConfig)
    authip: tuple = ()
    mdbport: int = DEFAULT_MDBPORT
    bind: str | None = None
    control: str | None = None
    metrics: str | None = None
    table: TableConfig = field(default_factory=lambda: TableConfig(enabled=True, direct=False))
    firewall: FirewallConfig | None = None   # on mdbport's requests; None: all allowed
    scenarios: tuple = ()           # ScenarioConfig (mbgw.config.scenario): TCP ones only
    config_file: str | None = None  # the file the settings came from (scenario ... --save)
    tcpto_ms: int = DEFAULT_TCPTO_MS   # TCP scenarios: the time for a transaction with a server
    tls: TlsConfig = field(default_factory=TlsConfig)    # on the table's server
    web: WebConfig = field(default_factory=WebConfig)   # [web]: the web console
    mqtt: MqttConfig = field(default_factory=MqttConfig)   # [mqtt]: northbound MQTT
    request_timeout_ms: int = DEFAULT_REQUEST_TIMEOUT_MS   # [net] request-timeout
    location: str = DEFAULT_LOCATION   # [general] location, the guide's set location

    @property
    def table_on(self) -> bool:
        return True

    def __post_init__(self) -> None:
        if self.mdbport == 0 and not self.tls.enabled:
            raise ConfigError("mdbport 0 turns plain Modbus TCP off: it needs TLS (--tls-cert)",
                              key="mdbport")
        if len(self.authip) > MAX_AUTHIP:
            raise ConfigError(f"authip: at most {MAX_AUTHIP} addresses, got {len(self.authip)}",
                              key="authip")
        object.__setattr__(self, "authip", tuple(parse_ip("authip", a) for a in self.authip))
