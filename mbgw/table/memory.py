"""The exchange table: the only owner of the C core's table calls.  Requests are answered by
C under the table's lock (a reader never sees half of a write); the operator's reads and
writes go through the same lock."""
from collections.abc import Iterable

from mbgw._ffi import ffi, lib
from mbgw.config.model import TABLE_FUNCTIONS
from mbgw.errors import TableError

REGISTERS = 0x10000
BITS = 0x10000                  # bit B: bit B % 16 of register B // 16
OUTPUTS = range(0x0800, 0x1000)
FREE_ZONE = range(0x1000, 0x8000)
CONFIG_ZONE = range(0x8000, 0x10000)
PDU_MAX = lib.MBGW_PDU_MAX
WATCHES = lib.MBGW_TABLE_WATCHES       # watches of changed values, at most
MBAP_MAX = lib.MBGW_MBAP_MAX
EXCEPTION_CODES = 16
ILLEGAL_FUNCTION = 0x01
# FC 8, 17, 43: answered on every unit that reaches the table, whatever its function lists
IDENTITY_FUNCTIONS = frozenset((0x08, 0x11, 0x2B))
IDENTITY_OBJECTS = lib.MBGW_IDENT_OBJECTS
IDENTITY_OBJECT_MAX = lib.MBGW_IDENT_OBJECT_MAX
SERVER_ID_MAX = lib.MBGW_SERVER_ID_MAX
DIAGNOSTIC_COUNTERS = ("bus_messages", "bus_errors", "exceptions", "server_messages",
                       "no_response", "naks", "busy", "overruns")   # FC 8/11-18
_OUTCOMES = ("answered", "exception", "broadcast")   # the C counters' order (MBGW_TABLE_*)


def _function_mask(functions: Iterable[int]) -> int:
    mask = 0
    for function in functions:
        if function not in TABLE_FUNCTIONS:
            raise TableError(f"function {function}: the table answers only "
                             f"{', '.join(map(str, TABLE_FUNCTIONS))}")
        mask |= 1 << function
    return mask


def _c_bytes(data):
    """data for a `const uint8_t *` argument: bytes as they are, any other buffer through
    ffi.from_buffer (no copy either way)."""
    return data if type(data) is bytes else ffi.from_buffer(data)


def _check_range(address: int, count: int, limit: int, what: str) -> None:
    if not (0 <= address < limit and 1 <= count <= limit - address):
        raise TableError(f"{what} {address}+{count}: beyond the table "
                         f"(0..{limit - 1})")


class Responder:
    """Answers requests from one table in one thread, into a buffer of its own (260 bytes,
    allocated once): the reply a method returns is a view of it, valid until its next call.
    One per thread that answers requests.  A serial slave's responder has its own function
    list (`serial_functions`, VPGate 3.7); the others answer the table's `functions`."""

    __slots__ = ("_table", "buffer", "reply", "functions_mask")

    def __init__(self, table: "Table", functions: Iterable[int] | None = None) -> None:
        self._table = table
        self.buffer = ffi.new("uint8_t[]", MBAP_MAX)
        self.reply = memoryview(ffi.buffer(self.buffer))
        self.functions_mask = None if functions is None else _function_mask(functions)

    def _refused(self, function: int) -> bool:
        """A function the table answers (its mask is both lists) but not for this side."""
        mask = self.functions_mask if self.functions_mask is not None \
            else self._table.tcp_mask
        return mask is not None and not (function < 32 and mask >> function & 1) \
            and function not in IDENTITY_FUNCTIONS

    def _count_refused(self, broadcast: bool) -> None:
        lib.mbgw_table_count_refused(self._table._t, broadcast)

    def answer_mbap_into(self, frame, broadcast: bool = False) -> int:
        """Answer a whole Modbus TCP frame (MBAP header + PDU, bytes or a buffer): the reply's
        length in .reply (transaction id and unit id kept), 0 for none (broadcast), -EBADMSG
        for a header whose protocol id or length field is wrong."""
        if len(frame) > 7 and self._refused(frame[7]) and frame[2] == frame[3] == 0 \
                and frame[4] << 8 | frame[5] == len(frame) - 6:
            self._count_refused(broadcast)
            if broadcast:
                return 0
            reply = self.reply
            reply[0:4] = frame[0:4]
            reply[4:9] = bytes((0, 3, frame[6], frame[7] | 0x80, ILLEGAL_FUNCTION))
            return 9
        return lib.mbgw_table_answer_mbap(self._table._t, _c_bytes(frame), len(frame),
                                          self.buffer, broadcast)

    def answer_mbap(self, frame, broadcast: bool = False) -> memoryview | None:
        """answer_mbap_into's reply as a view of .reply, None when there is none."""
        n = self.answer_mbap_into(frame, broadcast)
        return self.reply[:n] if n > 0 else None

    def answer_into(self, pdu, broadcast: bool = False) -> int:
        """Answer a request PDU (function code first): the reply PDU's length in .reply, 0
        for none (broadcast, or an empty PDU)."""
        if len(pdu) and self._refused(pdu[0]):
            self._count_refused(broadcast)
            if broadcast:
                return 0
            self.reply[0:2] = bytes((pdu[0] | 0x80, ILLEGAL_FUNCTION))
            return 2
        return lib.mbgw_table_answer(self._table._t, _c_bytes(pdu), len(pdu),
                                     self.buffer, broadcast)

    def answer_identity(self, pdu) -> memoryview | None:
        """The gateway unit's answer: the identity functions as answer does, any other
        function 0x01."""
        if len(pdu) and pdu[0] not in IDENTITY_FUNCTIONS:
            self._count_refused(False)
            self.reply[0:2] = bytes((pdu[0] | 0x80, ILLEGAL_FUNCTION))
            return self.reply[:2]
        return self.answer(pdu)

    def answer(self, pdu, broadcast: bool = False) -> memoryview | None:
        """answer_into's reply PDU as a view of .reply, None when there is none."""
        n = self.answer_into(pdu, broadcast)
        return self.reply[:n] if n > 0 else None


class Table:
    """The 65,536 registers, zero at the start, answering `functions`."""

    def __init__(self, functions: Iterable[int] = TABLE_FUNCTIONS) -> None:
        t = lib.mbgw_table_new()
        if t == ffi.NULL:
            raise MemoryError("the exchange table")
        self._t = ffi.gc(t, lib.mbgw_table_free)
        self._down = None            # the flags C reads at each FC 7, kept alive here
        self.tcp_mask: int | None = None   # with serial functions of their own: the others'
        self.set_functions(functions)
        self._own = Responder(self)
        self.reply_buffer = self._own.buffer

    def responder(self, functions: Iterable[int] | None = None) -> Responder:
        """A responder with its own reply buffer, for one thread; functions: its own list,
        which must be within the table's (set_functions)."""
        return Responder(self, functions)

    def answer(self, pdu: bytes, broadcast: bool = False) -> bytes | None:
        """The reply PDU to a request PDU, None when there is none (a broadcast).  Allocates
        its reply: the hot paths use a responder."""
        rsp = ffi.new("uint8_t[]", PDU_MAX)
        n = lib.mbgw_table_answer(self._t, _c_bytes(pdu), len(pdu), rsp, broadcast)
        return bytes(ffi.buffer(rsp, n)) if n > 0 else None

    def answer_mbap_into(self, frame, broadcast: bool = False) -> int:
        """Responder.answer_mbap_into into the table's own reply_buffer: for one thread only."""
        return self._own.answer_mbap_into(frame, broadcast)

    def read(self, address: int, count: int = 1) -> list[int]:
        """count registers from address."""
        _check_range(address, count, REGISTERS, "register")
        out = ffi.new("uint16_t[]", count)
        lib.mbgw_table_read(self._t, address, count, out)
        return list(out)

    def read_bits(self, address: int, count: int = 1) -> list[int]:
        """count bits (0 or 1) from bit address: bit B is bit B % 16 of register B // 16."""
        _check_range(address, count, BITS, "bit")
        first = address // 16
        registers = self.read(first, (address + count - 1) // 16 - first + 1)
        return [registers[b // 16 - first] >> (b % 16) & 1
                for b in range(address, address + count)]

    def write(self, address: int, values: Iterable[int]) -> None:
        """Write registers from address, all or none.  Raises TableError naming the address
        when they go beyond the table or into the configuration zone, or a value is not 16
        bits."""
        values = list(values)
        _check_range(address, len(values), REGISTERS, "register")
        for offset, value in enumerate(values):
            if not 0 <= value <= 0xFFFF:
                raise TableError(f"register {address + offset}: value {value} is not 0..65535")
        if address + len(values) > CONFIG_ZONE.start:
            raise TableError(f"register {max(address, CONFIG_ZONE.start)}: the configuration "
                             f"zone (0x8000-0xFFFF) is read-only")
        lib.mbgw_table_write(self._t, address, len(values), ffi.new("uint16_t[]", values))

    def write_bits(self, address: int, packed, count: int) -> None:
        """Write count bits from bit address (bit B: bit B % 16 of register B // 16), packed
        as in a Modbus PDU (first bit in the least significant bit of the first byte), under
        the table's lock: the other bits of those registers are kept, whoever writes them."""
        _check_range(address, count, BITS, "bit")
        if len(packed) < (count + 7) // 8:
            raise TableError(f"bit {address}+{count}: {len(packed)} bytes of bits is too few")
        if (address + count - 1) // 16 >= CONFIG_ZONE.start:
            raise TableError("the configuration zone (0x8000-0xFFFF) is read-only")
        lib.mbgw_table_write_bits(self._t, address, count, _c_bytes(packed))

    def set_config(self, address: int, values: Iterable[int]) -> None:
        """Fill the configuration zone (what identity computes); raises TableError outside it."""
        values = list(values)
        _check_range(address, len(values), REGISTERS, "register")
        if address < CONFIG_ZONE.start:
            raise TableError(f"register {address}: not in the configuration zone "
                             f"(0x8000-0xFFFF)")
        lib.mbgw_table_set_config(self._t, address, len(values), ffi.new("uint16_t[]", values))

    def unwritten(self, address: int, count: int) -> int | None:
        """The first register of [address, address + count) that nobody has written since the
        table was made (a Modbus write, the operator, a scenario's read, the persistence
        file, the configuration zone's content), None when all were written."""
        _check_range(address, count, REGISTERS, "register")
        first = lib.mbgw_table_unwritten(self._t, address, count)
        return None if first < 0 else first

    def set_functions(self, functions: Iterable[int],
                      serial_functions: Iterable[int] | None = None) -> None:
        """The function codes answered; any other is exception 0x01.  serial_functions:
        master mode's serial slave's own list; the table then answers both lists, and a
        responder without a list of its own (the TCP side's) only `functions`."""
        mask = _function_mask(functions)
        if serial_functions is None:
            self.tcp_mask = None
            lib.mbgw_table_set_functions(self._t, mask)
        else:
            lib.mbgw_table_set_functions(self._t, mask | _function_mask(serial_functions))
            self.tcp_mask = mask

    def set_identity(self, objects: "list[bytes]", server_id: bytes) -> None:
        """FC 43/14's objects 0-6 (each at most IDENTITY_OBJECT_MAX bytes) and FC 17's bytes
        after its byte count (server id, run indicator, additional data)."""
        if len(objects) != IDENTITY_OBJECTS:
            raise TableError(f"{len(objects)} identity objects: FC 43/14 has "
                             f"{IDENTITY_OBJECTS}")
        for number, value in enumerate(objects):
            if lib.mbgw_table_set_identity(self._t, number, value, len(value)) < 0:
                raise TableError(f"identity object {number}: {len(value)} bytes, at most "
                                 f"{IDENTITY_OBJECT_MAX}")
        if lib.mbgw_table_set_server_id(self._t, server_id, len(server_id)) < 0:
            raise TableError(f"server id: {len(server_id)} bytes, at most {SERVER_ID_MAX}")

    def count_bad_frame(self) -> None:
        """FC 8/11 and 12: a frame for the table that framed nothing (a serial slave's bad CRC
        or length)."""
        lib.mbgw_table_count_bad_frame(self._t)

    def diagnostics(self) -> dict[str, int]:
        """FC 8's counters 11-18 by name (DIAGNOSTIC_COUNTERS), since start or the last FC
        8/10."""
        out = ffi.new("uint16_t[]", len(DIAGNOSTIC_COUNTERS))
        lib.mbgw_table_diagnostics(self._t, out)
        return dict(zip(DIAGNOSTIC_COUNTERS, out, strict=True))

    def set_flags(self, line_down: bool | None = None,
                  scenario_error: bool | None = None) -> None:
        """FC 7's bits 0 (the serial line is down) and 1 (a scenario is in error); a flag not
        given keeps its value (the line thread and the scenarios each own one)."""
        if line_down is not None:
            lib.mbgw_table_set_flag(self._t, lib.MBGW_TABLE_LINE_DOWN, int(line_down))
        if scenario_error is not None:
            lib.mbgw_table_set_flag(self._t, lib.MBGW_TABLE_SCENARIO_ERROR, int(scenario_error))

    def set_stale(self, address: int, count: int, on: bool) -> None:
        """Mark registers [address, address + count) stale (on) or current: a read (FC 1-4,
        FC 23's read part) touching a stale register is answered 0x0B, "gateway target failed
        to respond" (a scenario whose data is older than its stale-after)."""
        _check_range(address, count, REGISTERS, "register")
        lib.mbgw_table_set_stale(self._t, address, count, int(on))

    def watch_down(self, down: bytearray | None) -> None:
        """FC 7's bit 2: any of these 256 flags (HealthRule.down, by serial address) set,
        read by C at each FC 7; None: no device is ever down."""
        self._down = None if down is None else ffi.from_buffer("uint8_t[]", down)
        lib.mbgw_table_watch_down(self._t, ffi.NULL if down is None else self._down)

    def watch(self, address: int, count: int, fd: int = -1, first_writes: bool = False) -> int:
        """Watch [address, address + count) for changed values: the watch's id, for
        take_change.  fd: an eventfd written once when a change comes after a take (-1: none).
        first_writes: a register's first write since start is a change even when it stores
        the value the table held.  Raises TableError beyond the table or when every watch is
        in use."""
        _check_range(address, count, REGISTERS, "register")
        watch = lib.mbgw_table_watch(self._t, address, count, fd, int(first_writes))
        if watch < 0:
            raise TableError(f"no room for another watch of the table "
                             f"({WATCHES} in use)")
        return watch

    def unwatch(self, watch: int) -> None:
        lib.mbgw_table_unwatch(self._t, watch)

    def take_change(self, watch: int, count: int) -> list[int] | None:
        """The watched range's values if one changed since the last take (the flag cleared
        under the same lock as the copy, so no change is lost), else None.  count: the
        range's length."""
        values = ffi.new("uint16_t[]", count)
        if not lib.mbgw_table_take_change(self._t, watch, values):
            return None
        return list(values)

    @property
    def persist_generation(self) -> int:
        """Grows with each write that changed a value of the outputs or the free zone."""
        return lib.mbgw_table_persist_generation(self._t)

    def counts(self) -> dict:
        """{"requests_by_function": {fc: {"answered": n, "exception": n, "broadcast": n}},
        "exceptions_by_code": {code: n}}: the table's functions always, any other code that
        was asked; the codes of the exceptions sent."""
        by_function = ffi.new("uint64_t[]", 256 * len(_OUTCOMES))
        by_exception = ffi.new("uint64_t[]", EXCEPTION_CODES)
        lib.mbgw_table_counts(self._t, by_function, by_exception)
        requests = {}
        for fc in range(256):
            row = by_function[fc * 3:fc * 3 + 3]
            if fc in TABLE_FUNCTIONS or any(row):
                requests[fc] = dict(zip(_OUTCOMES, row, strict=True))
        return {"requests_by_function": requests,
                "exceptions_by_code": {code: by_exception[code]
                                       for code in range(EXCEPTION_CODES) if by_exception[code]}}

    def reset_counts(self) -> None:
        lib.mbgw_table_reset_counts(self._t)
