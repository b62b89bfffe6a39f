"""The configuration zone's content (0x8000..., read-only to Modbus): who answers and how it is
set, as documented in mbgw.toml(5), THE CONFIGURATION ZONE.  Computed from the settings at
start and at each reload; nothing else writes the zone.  The same identity on the wire:
FC 43/14's objects and FC 17's server id (mbgw.toml(5), THE IDENTITY FUNCTIONS)."""
import socket
from typing import TYPE_CHECKING

import mbgw
from mbgw.config.model import PROTOCOLS
from mbgw.table.memory import IDENTITY_OBJECT_MAX

if TYPE_CHECKING:
    from mbgw.config.model import MasterConfig, SlaveConfig
    from mbgw.config.transparent import TransparentModeConfig
    from mbgw.table.memory import Table

VENDOR = "mbgw"
PRODUCT = "mbgw Modbus gateway"
ZONE_START = 0x8000
# (registers) of each field, in the order they follow each other from ZONE_START
VENDOR_REGISTERS = 16          # 0x8000-0x800F
PRODUCT_REGISTERS = 16         # 0x8010-0x801F
VERSION_REGISTERS = 8          # 0x8020-0x8027
MODES = {"slave": 1, "master": 2, "transparent": 3}      # 0x8028
PROTOCOL_CODES = {name: code for code, name in enumerate(PROTOCOLS)}   # rtu 0, ascii 1
UNIT_MASK_REGISTERS = 16       # 256 unit ids, one bit each
LOCATION_REGISTERS = 15        # 0x8044-0x8052: the guide's 30 bytes
SERVER_ID = b"mbgw"
RUN_INDICATOR_ON = b"\xff"


def ascii_registers(text: str, registers: int) -> list[int]:
    """text as ASCII, two characters a register, high byte first, NUL-padded (cut to fit)."""
    data = text.encode("ascii", "replace")[:2 * registers].ljust(2 * registers, b"\0")
    return [data[i] << 8 | data[i + 1] for i in range(0, len(data), 2)]


def long_registers(value: int) -> list[int]:
    """A 32-bit value as two registers, high word first."""
    return [value >> 16 & 0xFFFF, value & 0xFFFF]


def mask_registers(bits, registers: int) -> list[int]:
    """Bit n of the mask (n < 16 * registers) set for each n in bits: bit n % 16 (0 = least
    significant) of register n // 16, as the table's bit functions number bits."""
    words = [0] * registers
    for n in bits:
        words[n // 16] |= 1 << n % 16
    return words


def zone(settings: "SlaveConfig | MasterConfig | TransparentModeConfig", mode: str) -> list[int]:
    """The registers from 0x8000, in the documented layout."""
    serial, table = settings.serial, settings.table
    return [
        *ascii_registers(VENDOR, VENDOR_REGISTERS),
        *ascii_registers(PRODUCT, PRODUCT_REGISTERS),
        *ascii_registers(mbgw.__version__, VERSION_REGISTERS),
        MODES[mode],                                         # 0x8028
        *long_registers(serial.baudrate),                    # 0x8029-0x802A
        serial.format.data_bits,                             # 0x802B
        ord(serial.format.parity.upper()),                   # 0x802C
        serial.format.stop_bits,                             # 0x802D
        PROTOCOL_CODES[serial.protocol],                     # 0x802E
        *long_registers(sum(1 << fc for fc in table.functions)),   # 0x802F-0x8030
        table.address if mode == "master" else 0,            # 0x8031
        int(table.direct) if mode == "slave" else 0,         # 0x8032
        *mask_registers(table.units, UNIT_MASK_REGISTERS),   # 0x8033-0x8042
        table.port if mode == "master" else 0,               # 0x8043
        *ascii_registers(settings.location, LOCATION_REGISTERS),   # 0x8044-0x8052
    ]


def device_objects(mode: str, host: str) -> list[bytes]:
    """FC 43/14's objects 0-6: VendorName, ProductCode, MajorMinorRevision, VendorUrl (none),
    ProductName, ModelName (the mode), UserApplicationName (the host's name)."""
    texts = [VENDOR, "mbgw", mbgw.__version__, "", PRODUCT, mode, host]
    return [text.encode("ascii", "replace")[:IDENTITY_OBJECT_MAX] for text in texts]


def server_id() -> bytes:
    """FC 17's bytes after the byte count: the server id, the run indicator (on), the
    version."""
    return SERVER_ID + RUN_INDICATOR_ON + mbgw.__version__.encode("ascii")


def fill(table: "Table", settings: "SlaveConfig | MasterConfig | TransparentModeConfig",
         mode: str) -> None:
    """Write the zone's content and the identity functions' strings into the table (at
    start and after a reload)."""
    table.set_config(ZONE_START, zone(settings, mode))
    table.set_identity(device_objects(mode, socket.gethostname()), server_id())
