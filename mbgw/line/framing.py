"""How a frame looks on the serial line: RTU (binary, CRC, ended by silence) or ASCII
(':' hex LRC CR LF).  Each framing sends an ADU (address + PDU) and receives one, checked."""
import time

from mbgw.line import native
from mbgw.protocol import pdu
from mbgw.errors import FrameError
from mbgw.line.port import SerialLine

# receive(): the reply goes nowhere before it is returned
NO_FORWARD = (-1, 0, 0, False, native.NO_COUNTER)


class RtuFraming:
    def __init__(self, line: SerialLine) -> None:
        self.line = line
        self.port = line.port
        self.inter_frame_us = line.cfg.t35_us
        self._end_us = line.cfg.end_of_frame_us
        # the end-of-frame silence: a longer gap ends a frame, or a burst of noise
        self.port.set_byte_timeout(self._end_us)
        self.last_rx_ns = 0
        self.foreign_address = -1     # set when receive() returns None
        self.sent = -1
        self.sent_end_ns = 0

    def send(self, adu: bytes) -> int:
        return self.line.transmit_rtu(adu)

    def receive(self, adu: bytes, deadline: int, forward=NO_FORWARD) -> bytes | None:
        """address + PDU of a frame with a valid CRC from adu's address; None: another
        address.  Noise before the reply is skipped and counted (noise_bytes).  forward:
        (socket fd, tid, unit, yield, in-flight counter) of the client to which a reply that
        answers adu goes at once (self.sent: its bytes the socket took, -1 none;
        native.Port.receive_reply tells the rest).  Raises LineTimeout, ChecksumError,
        FrameError."""
        self.sent = -1
        try:
            frame = self.port.receive_reply(adu, deadline, *forward)
        finally:
            self._count_noise()
        return self._received(frame)

    def exchanges(self, adu: bytes) -> bool:
        """exchange() can take adu: a function code of pdu.LIBMODBUS_FRAMED, on a line
        libmodbus writes to."""
        return adu[1] in pdu.LIBMODBUS_FRAMED and self.line.libmodbus_sends

    def exchange(self, adu: bytes, stout_ns: int, forward=NO_FORWARD,
                 taken: bool = False) -> bytes | None:
        """send(adu) and receive() with the deadline stout_ns after the request, in one C
        call, so that nothing runs between the write and the wait for the reply (taken: the
        port took adu from its client and exchanged it already).  self.sent_end_ns: when the
        request's last byte left (raising SerialError, the write failed: the line is lost)."""
        self.sent = -1
        port = self.port
        try:
            if taken:
                frame = port.exchanged()
            else:
                frame = port.exchange(adu, self.line.char_ns, stout_ns, *forward)
        finally:
            self.sent_end_ns = port.sent_end_ns
            if self.sent_end_ns >= 0:        # else the write failed
                self.line.sent_rtu(len(adu))
            self._count_noise()
        return self._received(frame)

    def _count_noise(self) -> None:
        """After a receive, whatever its outcome: the bytes it read that were in no frame."""
        port = self.port
        self.last_rx_ns = port.last_byte_ns
        counters = self.line.counters
        counters.noise_bytes += port.noise
        counters.bytes_received += port.noise

    def _received(self, frame: bytes | None) -> bytes | None:
        port = self.port
        if frame is None:
            self.line.counters.bytes_received += port.dropped_length
            self.foreign_address = port.foreign_address
            return None
        self.sent = port.sent
        self.line.counters.bytes_received += len(frame)
        return frame[:-2]

    def receive_unchecked(self, adu: bytes, deadline: int) -> bytes:
        """nocheck: whatever came until the end-of-frame silence, CRC removed unchecked."""
        frame = self.port.read_reply(len(adu), deadline, self._end_us, True)
        self.last_rx_ns = self.port.last_byte_ns
        self.line.counters.bytes_received += len(frame)
        return frame[:-2]

    def resync(self) -> None:
        """Skip the rest of a broken frame, up to the end-of-frame silence after its last
        byte (nothing, when a silence already ended it): noise."""
        skipped = self.port.wait_quiet(self.last_rx_ns, self._end_us)
        if skipped:
            self.last_rx_ns = time.monotonic_ns()
            self.line.counters.noise_bytes += skipped
            self.line.counters.bytes_received += skipped


class AsciiFraming:
    inter_frame_us = 0     # ASCII frames are delimited by ':' and CR LF, not by silence
    sent = -1              # replies are never forwarded before they are checked here

    def __init__(self, line: SerialLine) -> None:
        self.line = line
        self.port = line.port
        self._interchar_us = line.cfg.ascii_timeout_ms * 1000
        self.last_rx_ns = 0
        self.foreign_address = -1     # set when receive() returns None

    def send(self, adu: bytes) -> int:
        return self.line.transmit(native.ascii_encode(adu))

    def exchanges(self, adu: bytes) -> bool:
        return False

    def _read(self, deadline: int) -> bytes:
        """One frame; what came outside it (before its ':', a frame cut short) is noise."""
        port = self.port
        counters = self.line.counters
        try:
            frame = port.read_ascii(deadline, self._interchar_us)
        finally:
            self.last_rx_ns = port.last_byte_ns
            counters.noise_bytes += port.noise
            counters.bytes_received += port.noise
        counters.bytes_received += len(frame)
        return frame

    def receive(self, adu: bytes, deadline: int, forward=NO_FORWARD) -> bytes | None:
        decoded = native.ascii_decode(self._read(deadline))
        if len(decoded) < 2:
            raise FrameError("frame too short")
        if decoded[0] != adu[0]:
            self.foreign_address = decoded[0]
            return None
        return decoded

    def receive_unchecked(self, adu: bytes, deadline: int) -> bytes:
        """nocheck: the frame's bytes, LRC removed unchecked."""
        frame = self._read(deadline)
        body = frame[1:-2]
        try:
            raw = bytes.fromhex(body.decode("ascii"))
        except ValueError:
            raise FrameError("not hexadecimal") from None
        return raw[:-1]

    def resync(self) -> None:
        self.last_rx_ns = time.monotonic_ns()


def framing_for(line: SerialLine):
    return AsciiFraming(line) if line.cfg.protocol == "ascii" else RtuFraming(line)
