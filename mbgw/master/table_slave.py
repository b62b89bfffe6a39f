"""The exchange table's serial slave on a line in master mode: mbgw answers, as a slave of
local data, the requests a face routes to the table (VPGate 3.7), and writes a broadcast's
writes into it.  It counts its requests, invalid CRCs and lengths, and failed sends (VPGate
8.5); the face writes the answer on its line (`send`)."""
import time
from collections.abc import Callable

from mbgw.errors import SerialError
from mbgw.line import native
from mbgw.master.trace import MasterTracer
from mbgw.ops.counters import TableSlaveCounters
from mbgw.ops.trace import Outcome

# send(address, reply) -> False when the master moved on before the line was quiet
Send = Callable[[int, bytes], bool]


class TableSlave:
    def __init__(self, table, functions: tuple[int, ...]) -> None:
        """table: mbgw.table.memory.Table; functions: those its serial slave answers."""
        self.table = table
        self.counters = TableSlaveCounters()
        self._responder = table.responder(functions)

    def set_functions(self, functions: tuple[int, ...]) -> None:
        self._responder = self.table.responder(functions)

    def rejected(self, checksum: bool) -> None:
        """A frame for the table's address that the receiver rejected: a bad check, else a
        bad length."""
        if checksum:
            self.counters.crc_errors += 1
        else:
            self.counters.length_errors += 1
        self.table.count_bad_frame()

    def serve(self, adu: bytes, send: Send, tracer: MasterTracer | None,
              identity: bool = False) -> None:
        """Answer a request (ADU without check) from the table; tracer: while someone
        traces; identity: the gateway unit's request, which only the identity functions
        answer."""
        counts = self.counters
        counts.requests += 1
        if length_error(adu):
            counts.length_errors += 1       # the table answers it 0x03
        received_ns = time.monotonic_ns()
        request = memoryview(adu)[1:]
        reply = self._responder.answer_identity(request) if identity \
            else self._responder.answer(request)
        outcome: str = Outcome.TABLE
        if reply is not None:
            try:
                sent = send(adu[0], reply)
            except SerialError:
                counts.send_failures += 1
                raise
            if not sent:
                outcome += ", abandoned: the master moved on"
        if tracer is not None:
            tracer.table(adu, reply, outcome, (time.monotonic_ns() - received_ns) / 1e6)

    def broadcast(self, adu: bytes, tracer: MasterTracer | None) -> None:
        """A broadcast's writes go into the table too (its reads are ignored)."""
        self._responder.answer(memoryview(adu)[1:], True)
        if tracer is not None:
            tracer.table(adu, None, f"{Outcome.TABLE}: broadcast", 0.0)


def length_error(adu: bytes) -> bool:
    """The frame's length, or its byte count, is not what its function code and quantity say
    (VPGate 8.5 "invalid length")."""
    expected = native.rtu_request_length(adu + b"\0\0")
    if expected != native.LEN_UNKNOWN and expected != len(adu) + native.CRC_LEN:
        return True
    function = adu[1]
    if function in (0x0F, 0x10):
        quantity = int.from_bytes(adu[4:6], "big")
        return adu[6] != ((quantity + 7) // 8 if function == 0x0F else 2 * quantity)
    if function == 0x17:
        return adu[10] != 2 * int.from_bytes(adu[8:10], "big")
    return False
