"""A read scenario's table data as the value it publishes, and a value written from MQTT as
the Modbus request that writes it to the scenario's device.  `swap = "words"` is CDAB,
`"bytes"` BADC; a string is two characters a register, high byte first, trailing NULs
dropped; a bool of a register is value != 0."""
import math
import struct

from mbgw.config.scenario import ScenarioConfig

Value = int | float | bool | str
NUMBERS = ("uint16", "int16", "uint32", "int32", "float32")
_FORMATS = {"uint16": ">H", "int16": ">h", "uint32": ">I", "int32": ">i", "float32": ">f"}
_RANGES = {"uint16": (0, 0xFFFF), "int16": (-0x8000, 0x7FFF), "uint32": (0, 0xFFFFFFFF),
           "int32": (-0x80000000, 0x7FFFFFFF)}
COIL_ON = 0xFF00


class WriteRefused(ValueError):
    """A value that the scenario's type cannot carry; the message says why."""


def value_type(sc: ScenarioConfig) -> str:
    """The scenario's type: its `type`, else one bit (bool) or one register (uint16) each."""
    if sc.value_type is not None:
        return sc.value_type
    return "bool" if sc.bits else "uint16"


def element_names(sc: ScenarioConfig) -> list[str]:
    """The metric names of a scenario: its name for one value, NAME/0, NAME/1 ... for an
    untyped scenario of several registers or bits."""
    if sc.value_type is not None or sc.quantity == 1:
        return [sc.name]
    return [f"{sc.name}/{i}" for i in range(sc.quantity)]


def _ordered(registers: list[int], swap: str) -> bytes:
    """The registers' bytes in ABCD order."""
    if swap == "words":
        registers = registers[::-1]
    data = b"".join(r.to_bytes(2, "big") for r in registers)
    if swap == "bytes":
        data = bytes(b for pair in zip(data[1::2], data[0::2], strict=True) for b in pair)
    return data


def decode(sc: ScenarioConfig, words: list[int]) -> list[Value]:
    """The values of a scenario from its table data: registers, or bits for a bit
    function."""
    if sc.bits:
        return [bool(b) for b in words]
    kind = value_type(sc)
    if sc.value_type is None:
        if sc.swap == "none":
            return list(words)
        return [int.from_bytes(_ordered([w], sc.swap), "big") for w in words]
    data = _ordered(words, sc.swap)
    if kind == "bool":
        return [any(data)]
    if kind == "string":
        return [data.rstrip(b"\0").decode("latin-1")]
    return [struct.unpack(_FORMATS[kind], data)[0]]


def encode(sc: ScenarioConfig, name: str, value: object) -> bytes:
    """The write PDU that puts value (metric `name` of sc) into sc's device: FC 6 for one
    register, 16 for more, 5 or 15 for bits.  Raises WriteRefused."""
    kind = value_type(sc)
    offset = 0 if name == sc.name else int(name.rsplit("/", 1)[1])
    address = sc.address + offset
    if sc.bits:
        on = _as_bool(value)
        return struct.pack(">BHH", 5, address, COIL_ON if on else 0)
    if sc.value_type is None:
        data = _as_int(value, 0, 0xFFFF).to_bytes(2, "big")
    elif kind == "bool":
        data = b"\0\1" if _as_bool(value) else b"\0\0"
    elif kind == "string":
        data = _string_bytes(value, sc.quantity)
    else:
        data = _number_bytes(kind, value)
    registers = _from_ordered(data, sc.swap)
    if len(registers) == 1:
        return struct.pack(">BHH", 6, address, registers[0])
    return struct.pack(f">BHHB{len(registers)}H", 16, address, len(registers),
                       2 * len(registers), *registers)


def _from_ordered(data: bytes, swap: str) -> list[int]:
    """ABCD bytes as the device's registers (the inverse of _ordered)."""
    if swap == "bytes":
        data = bytes(b for pair in zip(data[1::2], data[0::2], strict=True) for b in pair)
    registers = [int.from_bytes(data[i:i + 2], "big") for i in range(0, len(data), 2)]
    return registers[::-1] if swap == "words" else registers


def _number_bytes(kind: str, value: object) -> bytes:
    if kind == "float32":
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise WriteRefused(f"{value!r}: expected a number")
        return struct.pack(">f", value)
    low, high = _RANGES[kind]
    return struct.pack(_FORMATS[kind], _as_int(value, low, high))


def _string_bytes(value: object, quantity: int) -> bytes:
    if not isinstance(value, str):
        raise WriteRefused(f"{value!r}: expected a string")
    try:
        data = value.encode("latin-1")
    except UnicodeEncodeError:
        raise WriteRefused(f"{value!r}: Latin-1 characters only") from None
    if len(data) > 2 * quantity:
        raise WriteRefused(f"{value!r}: at most {2 * quantity} characters")
    return data.ljust(2 * quantity, b"\0")


def _as_int(value: object, low: int, high: int) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise WriteRefused(f"{value!r}: expected a whole number {low}..{high}")
    return value


def _as_bool(value: object) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    raise WriteRefused(f"{value!r}: expected true or false")
