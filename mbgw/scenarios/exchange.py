"""A scenario's request and what its reply does (Modbus Application Protocol V1.1b3, section
6): the request PDU, its write data taken from the exchange table; the reply checked against
the request (exception, function, byte count, quantity, echo) and its read data stored in the
table.  The error kinds carry VPGate's messages (§8.2, §8.3)."""
import struct
from dataclasses import dataclass, field

from mbgw.config.scenario import ScenarioConfig
from mbgw.protocol.pdu import EXCEPTION_FLAG

COIL_ON = 0xFF00

# error kinds (the `kind` label of the metrics) and VPGate's messages
TIMEOUT = "timeout"
UNEXPECTED_FUNCTION = "unexpected-function"
UNEXPECTED_DATA = "unexpected-data"
CONNECTION_LOST = "connection-lost"
CONNECTION_REFUSED = "connection-refused"
TLS_REFUSED = "tls-refused"
DEVICE_DOWN = "device-down"        # demotion: the run skipped, not sent
SERVER_DOWN = "server-down"
FRAME_WITHOUT_REQUEST = "frame-without-request"   # no reply, but another's frame: a 2nd master?
EXCEPTION_KINDS = {0x01: "illegal-function", 0x02: "illegal-address", 0x03: "illegal-value",
                   0x04: "device-failure", 0x06: "busy", 0x0A: "path-unavailable",
                   0x0B: "target-failed"}
OTHER_EXCEPTION = "exception"
ERROR_MESSAGES = {
    TIMEOUT: "timeout, no answer from slave after retrying",
    "illegal-function": "received illegal function from slave (0x01)",
    "illegal-address": "received illegal data address from slave (0x02)",
    "illegal-value": "received illegal data value from slave (0x03)",
    "device-failure": "slave failed to execute request (0x04)",
    "busy": "slave is busy, cannot execute request (0x06)",
    "path-unavailable": "gateway path unavailable (0x0A)",
    "target-failed": "gateway target failed to respond (0x0B)",
    OTHER_EXCEPTION: "received an exception from slave",
    UNEXPECTED_FUNCTION: "received unexpected function in answer",
    UNEXPECTED_DATA: "received unexpected data/quantity in answer",
    CONNECTION_LOST: "TCP connection lost",
    CONNECTION_REFUSED: "connection refused",
    TLS_REFUSED: "connection refused: TLS handshake failed",
    DEVICE_DOWN: "device down",
    SERVER_DOWN: "server down",
    FRAME_WITHOUT_REQUEST: "frame received without request",
}
RETRYING = "slave not responding, retrying..."   # VPGate 8.2, while a run retries
WAITING = "waiting for data"       # a write whose table registers nobody has written yet
ERROR_KINDS = tuple(ERROR_MESSAGES)


def error_message(kind: str, tcp: bool = False, code: int | None = None) -> str:
    """VPGate's message for an error kind; a TCP scenario's peer is a "server"."""
    message = ERROR_MESSAGES.get(kind, kind)
    if kind == OTHER_EXCEPTION and code is not None:
        message = f"received exception 0x{code:02X} from slave"
    return message.replace("slave", "server") if tcp else message


@dataclass(frozen=True)
class Result:
    """A run's outcome: ok, or an error kind (and the exception code of an exception)."""
    kind: str | None = None              # None: ok
    code: int | None = None
    data: list[int] = field(default_factory=list)   # what a read returned (registers or bits)
    packed: bytes = b""                  # a bit read's bytes as the reply packed them

    @property
    def ok(self) -> bool:
        return self.kind is None

    def message(self, tcp: bool = False) -> str:
        return "ok" if self.kind is None else error_message(self.kind, tcp, self.code)


OK = Result()


def request_pdu(sc: ScenarioConfig, table) -> bytes:
    """The scenario's request PDU; a write's data is the table's now."""
    fc = sc.function
    if fc in (1, 2, 3, 4):
        return struct.pack(">BHH", fc, sc.address, sc.quantity)
    if fc == 5:
        return struct.pack(">BHH", fc, sc.address, COIL_ON if table.read_bits(sc.table)[0] else 0)
    if fc == 6:
        return struct.pack(">BHH", fc, sc.address, table.read(sc.table)[0])
    if fc == 15:
        data = pack_bits(table.read_bits(sc.table, sc.quantity))
        return struct.pack(">BHHB", fc, sc.address, sc.quantity, len(data)) + data
    if fc == 16:
        values = table.read(sc.table, sc.quantity)
        return struct.pack(f">BHHB{sc.quantity}H", fc, sc.address, sc.quantity,
                           2 * sc.quantity, *values)
    assert sc.write_quantity is not None and sc.write_table is not None
    values = table.read(sc.write_table, sc.write_quantity)
    return struct.pack(f">BHHHHB{sc.write_quantity}H", fc, sc.address, sc.quantity,
                       sc.write_address, sc.write_quantity, 2 * sc.write_quantity, *values)


def pack_bits(bits: list[int]) -> bytes:
    """Bits, first in the least significant bit of the first byte (section 6.11)."""
    out = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def unpack_bits(data: bytes, count: int) -> list[int]:
    return [data[i // 8] >> (i % 8) & 1 for i in range(count)]


def check_reply(sc: ScenarioConfig, request: bytes, reply: bytes) -> Result:
    """The reply's verdict and the data it read (not stored)."""
    fc = sc.function
    if len(reply) >= 2 and reply[0] == fc | EXCEPTION_FLAG:
        code = reply[1]
        return Result(EXCEPTION_KINDS.get(code, OTHER_EXCEPTION), code)
    if not reply or reply[0] != fc:
        return Result(UNEXPECTED_FUNCTION)
    if fc in (1, 2):
        size = (sc.quantity + 7) // 8
        if len(reply) != 2 + size or reply[1] != size:
            return Result(UNEXPECTED_DATA)
        return Result(data=unpack_bits(reply[2:], sc.quantity), packed=reply[2:])
    if fc in (3, 4, 23):
        if len(reply) != 2 + 2 * sc.quantity or reply[1] != 2 * sc.quantity:
            return Result(UNEXPECTED_DATA)
        return Result(data=list(struct.unpack(f">{sc.quantity}H", reply[2:])))
    # writes: 5 and 6 echo the request, 15 and 16 its address and quantity
    if len(reply) != 5 or reply[1:5] != request[1:5]:
        return Result(UNEXPECTED_DATA)
    return OK


def store(sc: ScenarioConfig, table, result: Result) -> None:
    """A read's data into the table: registers, or bits into register bits (under the
    table's lock, the registers' other bits kept)."""
    if sc.bits:
        table.write_bits(sc.table, result.packed, sc.quantity)
    else:
        table.write(sc.table, result.data)


def apply_reply(sc: ScenarioConfig, table, reply_pdu: bytes,
                request: bytes | None = None) -> Result:
    """Check the reply to the scenario's request (`request`: the PDU sent; built again from
    the scenario when not given, which only a write's echo check needs) and store what a read
    returned."""
    if request is None:
        request = request_pdu(sc, table)
    result = check_reply(sc, request, bytes(reply_pdu))
    if result.ok and sc.reads:
        store(sc, table, result)
    return result
