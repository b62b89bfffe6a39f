"""One Modbus RTU transaction on the line, as the serial master (slave mode).

Requests go out only after the line has been quiet for t3.5 (or the turnaround delay after a
broadcast).  Every frame that is not the reply -- bad CRC, another address, another function,
a size the request did not ask for -- is counted and dropped, and we keep listening until
stout has passed, as the spec's master does (Serial Line V1.02, 2.4.1).
"""
import logging
import time

from mbgw import native, pdu
from mbgw.config import SerialConfig
from mbgw.counters import Counters
from mbgw.errors import ChecksumError, FrameError, LineTimeout

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")


class RtuMaster:
    def __init__(self, port: native.Port, cfg: SerialConfig, counters: Counters,
                 retries: int = 0, turnaround_ms: int = 100) -> None:
        self.port = port
        self._counters = counters
        self._retries = retries
        self._t35_us = cfg.t35_us
        self._char_ns = cfg.char_ns
        self._stout_ns = cfg.stout_ms * 1_000_000
        self._turnaround_us = turnaround_ms * 1000
        self._quiet_from_ns = 0
        self._quiet_us = 0

    def transact(self, adu: bytes) -> bytes | None:
        """Send adu (address + PDU) and return the reply PDU; None for a broadcast.
        Raises LineTimeout when no valid reply came, SerialError when the port failed."""
        self._send(adu)
        if adu[0] == pdu.BROADCAST:
            self._counters.broadcasts += 1
            self._quiet_us = self._turnaround_us
            return None
        for attempt in range(self._retries + 1):
            if attempt:
                self._counters.retries += 1
                self._send(adu)
            reply = self._receive(adu)
            if reply is not None:
                return reply
        self._counters.timeouts += 1
        raise LineTimeout()

    def _send(self, adu: bytes) -> None:
        stale = self.port.wait_quiet(self._quiet_from_ns, self._quiet_us)
        if stale:
            self._counters.late_bytes += stale
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("tx %s", adu.hex(" "))
        self.port.send(adu)
        # The request is on the wire until its last character (and CRC) has gone out.
        self._quiet_from_ns = time.monotonic_ns() + (len(adu) + 2) * self._char_ns
        self._quiet_us = self._t35_us

    def _receive(self, adu: bytes) -> bytes | None:
        """The reply PDU, or None once stout has passed without one."""
        deadline = self._quiet_from_ns + self._stout_ns
        while True:
            try:
                frame = self._read_frame(adu, deadline)
            except LineTimeout:
                return None
            except ChecksumError:
                self._counters.crc_errors += 1
                self._resync()
                continue
            except FrameError:
                self._counters.invalid_frames += 1
                self._resync()
                continue
            if frame is None:
                self._counters.wrong_unit += 1
                continue
            if wire.isEnabledFor(logging.DEBUG):
                wire.debug("rx %s", frame.hex(" "))
            reply = frame[1:-2]
            if not reply or not pdu.reply_matches(adu[1:], reply):
                self._counters.wrong_function += 1
                continue
            if reply[0] & pdu.EXCEPTION_FLAG:
                self._counters.device_exceptions += 1
            return reply

    def _read_frame(self, adu: bytes, deadline: int) -> bytes | None:
        """One frame with a valid CRC from adu's address; None for another address."""
        function = adu[1]
        if function in pdu.LIBMODBUS_FRAMED:
            timeout_us = (deadline - time.monotonic_ns()) // 1000
            if timeout_us <= 0:
                raise LineTimeout()
            frame = self.port.receive_confirmation(adu[0], timeout_us)
            self._quiet_from_ns = time.monotonic_ns()
            return frame
        frame = self.port.read_reply(len(adu), deadline, self._t35_us, False)
        self._quiet_from_ns = self.port.last_byte_ns
        if len(frame) < 4 or self.port.last_byte_ns > deadline:
            raise FrameError("incomplete frame")
        if native.crc16(frame) != 0:
            raise ChecksumError()
        if frame[0] != adu[0]:
            return None
        return frame

    def _resync(self) -> None:
        """Skip the rest of a broken frame: what follows it without a t3.5 gap is not a frame."""
        self._counters.late_bytes += self.port.wait_quiet(time.monotonic_ns(), self._t35_us)
        self._quiet_from_ns = time.monotonic_ns()
