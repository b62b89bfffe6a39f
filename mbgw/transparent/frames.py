"""Transparent mode's frame rules (VPGate 3.8), no I/O.  Bytes are two to a register, the
first in the high half.  With --crc the CRC-16/MODBUS of a frame (low byte first) follows it
on the line, after the end characters or the data: it is checked and dropped on receipt, and
added when sending; the table never holds it."""
import struct

from mbgw.config.model import SerialConfig
from mbgw.config.transparent import TransparentConfig, registers_of
from mbgw.line.native import crc16

MAX_FRAME = 4096        # bytes without an end: dropped as incomplete (the line is out of step)
_CRC = struct.Struct("<H")


def to_registers(data: bytes) -> list[int]:
    if len(data) % 2:
        data += b"\0"
    return list(struct.unpack(f">{len(data) // 2}H", data))


def from_registers(values: list[int], size: int) -> bytes:
    return struct.pack(f">{len(values)}H", *values)[:size]


class Rules:
    """One setting's rules: frames on the line, the rx area's layout, the tx area's frame."""

    def __init__(self, cfg: TransparentConfig, serial: SerialConfig) -> None:
        self.cfg = cfg
        self.kind = cfg.eof
        self.end = cfg.end
        self.crc = 2 if cfg.crc else 0
        self.trigger = cfg.trigger
        self.eof_timeout_ms = cfg.eof_timeout_for(serial)
        self.rx_registers = registers_of(cfg.rx_size)
        self.tx_registers = registers_of(cfg.tx_size)

    # --- receiving ---

    def complete_length(self, data: bytearray) -> int | None:
        """The length of the whole frame data begins with (its CRC included), None while it
        is not all there (`timeout`: a frame ends only by silence)."""
        if not data or self.kind == "timeout":
            return None
        if self.end is None:                          # length: the first byte counts the rest
            need = 1 + data[0] + self.crc
        else:
            at = data.find(self.end)
            if at < 0:
                return None
            need = at + len(self.end) + self.crc
        return need if len(data) >= need else None

    def payload(self, wire: bytes) -> bytes | None:
        """The frame without its CRC; None when the CRC is wrong."""
        if not self.crc:
            return wire
        if len(wire) < 3 or crc16(wire[:-2]) != _CRC.unpack_from(wire, len(wire) - 2)[0]:
            return None
        return wire[:-2]

    def rx_area(self, payload: bytes, counter: int) -> tuple[list[int], bool]:
        """The rx area's registers for a received frame (the rest of the area zero), and
        whether the frame was cut to fit.  counter: the trigger's new value.  `timeout`: the
        length byte says how many bytes of the frame the area holds."""
        size = self.cfg.rx_size
        head = bytes([counter]) if self.trigger else b""
        if self.kind == "timeout":
            data = payload[:max(0, size - len(head) - 1)]
            head += bytes([len(data)])
        else:
            data = payload[:max(0, size - len(head))]
        area = (head + data)[:size].ljust(self.rx_registers * 2, b"\0")
        return to_registers(area), len(data) < len(payload)

    # --- sending ---

    def tx_frame(self, area: bytes, counter: int | None) -> tuple[bytes | None, int | None]:
        """What the tx area sends: (the frame with its CRC, or None: nothing; b"": refused),
        and the trigger counter now (None without --trigger).  counter: its last value."""
        if self.trigger:
            if area[0] == counter:
                return None, counter
            counter, area = area[0], area[1:]
        frame = self._frame(area)
        if frame and self.crc:
            frame += _CRC.pack(crc16(frame))
        return frame, counter

    def _frame(self, data: bytes) -> bytes | None:
        if self.end is not None:
            at = data.find(self.end)
            return b"" if at < 0 else data[:at + len(self.end)]
        if not data or data[0] + 1 > len(data):
            return b""
        if self.kind == "length":
            return data[:data[0] + 1]
        return data[1:data[0] + 1] or None          # timeout: the length byte is not sent


class Receiver:
    """Cuts the line's bytes into frames."""

    def __init__(self, rules: Rules) -> None:
        self.rules = rules
        self.pending = bytearray()

    def feed(self, data: bytes) -> tuple[list[bytes], bool]:
        """The frames data completes (wire bytes), the start of the next kept; and whether
        that start grew beyond MAX_FRAME (then it is dropped)."""
        pending = self.pending
        pending += data
        frames = []
        while (n := self.rules.complete_length(pending)) is not None:
            frames.append(bytes(pending[:n]))
            del pending[:n]
        if len(pending) <= MAX_FRAME:
            return frames, False
        pending.clear()
        return frames, True

    def quiet(self) -> bytes | None:
        """The line has been quiet for eof-timeout: the frame (`timeout`), or None: what had
        come is incomplete, dropped."""
        data, self.pending = bytes(self.pending), bytearray()
        return data if self.rules.kind == "timeout" else None
