"""A line's framing for its master (mbgw.slave.transaction.SerialMaster): how a frame looks on
the line.  A serial line's is RtuFraming (binary, CRC, ended by silence) or AsciiFraming (':'
hex LRC CR LF); a remote line's comes from mbgw.slave.remote_framing.  Each sends an ADU
(address + PDU) and receives one, checked: what came is a native.Reception, its frame address
+ PDU without the check bytes.
"""
import time

from mbgw.errors import ChecksumError, FrameError
from mbgw.line import native
from mbgw.line.native import NO_FORWARD, Forward, Reception
from mbgw.line.remote import RemoteLine
from mbgw.line.serial_line import SerialLine
from mbgw.protocol import pdu
from mbgw.slave.remote_framing import remote_framing


class RtuFraming:
    inter_frame_us: int

    def __init__(self, line: SerialLine) -> None:
        self.line = line
        self.port = line.port
        self.inter_frame_us = line.cfg.t35_us
        self._end_us = line.cfg.end_of_frame_us
        # the end-of-frame silence: a longer gap ends a frame, or a burst of noise
        self.port.set_byte_timeout(self._end_us)

    def send(self, adu: bytes) -> int:
        return self.line.transmit_rtu(adu)

    def receive(self, adu: bytes, deadline: int, forward: Forward = NO_FORWARD) -> Reception:
        """The next frame after adu, address + PDU (its CRC checked and removed); noise before it
        is skipped and counted (noise_bytes).  forward: the client to which a reply that
        answers adu goes at once (Reception.forwarded)."""
        return self._book(self.port.receive_reply(adu, deadline, forward))

    def exchanges(self, adu: bytes) -> bool:
        """exchange() can take adu: a function code of pdu.LIBMODBUS_FRAMED, on a line
        libmodbus writes to."""
        return adu[1] in pdu.LIBMODBUS_FRAMED and self.line.libmodbus_sends

    def exchange(self, adu: bytes, stout_ns: int, forward: Forward = NO_FORWARD) -> Reception:
        """send(adu) and receive() with the deadline stout_ns after the request, in one C
        call, so that nothing runs between the write and the wait for the reply.  Raises
        SerialError when the write failed (the line is lost)."""
        got = self.port.exchange(adu, self.line.char_ns, stout_ns, forward)
        self.line.sent_rtu(len(adu))
        return self._book(got)

    def exchanged(self, adu: bytes, got: Reception) -> Reception:
        """Count an exchange of adu that C made (exchange(), or the port's shortcut, which
        took adu from its client): got, what it received."""
        self.line.sent_rtu(len(adu))
        return self._book(got)

    def _book(self, got: Reception) -> Reception:
        """Count what a receive read."""
        counters = self.line.counters
        counters.noise_bytes += got.noise
        counters.bytes_received += got.noise + got.length
        return got

    def receive_unchecked(self, adu: bytes, deadline: int) -> Reception:
        """nocheck: whatever came until the end-of-frame silence, CRC removed unchecked."""
        got = self.port.read_reply(deadline, self._end_us)
        self.line.counters.bytes_received += got.length
        return got if got.frame is None else got._replace(frame=got.frame[:-2])

    def resync(self, last_byte_ns: int) -> int:
        """Skip the rest of a broken frame, up to the end-of-frame silence after its last
        byte (last_byte_ns; nothing, when a silence already ended it): noise.  Returns when
        the line last carried a byte."""
        skipped = self.port.wait_quiet(last_byte_ns, self._end_us)
        if not skipped:
            return last_byte_ns
        self.line.counters.noise_bytes += skipped
        self.line.counters.bytes_received += skipped
        return time.monotonic_ns()


class AsciiFraming:
    inter_frame_us = 0     # ASCII frames are delimited by ':' and CR LF, not by silence

    def __init__(self, line: SerialLine) -> None:
        self.line = line
        self.port = line.port
        self._interchar_us = line.cfg.ascii_timeout_ms * 1000

    def send(self, adu: bytes) -> int:
        return self.line.transmit(native.ascii_encode(adu))

    def exchanges(self, adu: bytes) -> bool:
        return False

    def _read(self, deadline: int) -> Reception:
        """One frame; what came outside it (before its ':', a frame cut short) is noise."""
        got = self.port.read_ascii(deadline, self._interchar_us)
        counters = self.line.counters
        counters.noise_bytes += got.noise
        counters.bytes_received += got.noise + got.length
        return got

    def receive(self, adu: bytes, deadline: int, forward: Forward = NO_FORWARD) -> Reception:
        """The next frame, address + PDU (its LRC checked and removed); replies are never
        forwarded before they are checked here."""
        got = self._read(deadline)
        if got.frame is None:
            return got
        try:
            decoded = native.ascii_decode(got.frame)
            if len(decoded) < 2:
                raise FrameError("frame too short")
        except (ChecksumError, FrameError) as fault:
            return got._replace(frame=None, fault=fault)
        if decoded[0] != adu[0]:
            return got._replace(frame=None, foreign_address=decoded[0], foreign=decoded)
        return got._replace(frame=decoded)

    def receive_unchecked(self, adu: bytes, deadline: int) -> Reception:
        """nocheck: the frame's bytes, LRC removed unchecked."""
        got = self._read(deadline)
        if got.frame is None:
            return got
        try:
            raw = bytes.fromhex(got.frame[1:-2].decode("ascii"))
        except ValueError:
            return got._replace(frame=None, fault=FrameError("not hexadecimal"))
        return got._replace(frame=raw[:-1])

    def resync(self, last_byte_ns: int) -> int:
        return time.monotonic_ns()


def framing_for(line: SerialLine | RemoteLine):
    """line's framing: a remote line's by its kind, a serial line's by its protocol."""
    if isinstance(line, RemoteLine):
        return remote_framing(line)
    return AsciiFraming(line) if line.cfg.protocol == "ascii" else RtuFraming(line)
