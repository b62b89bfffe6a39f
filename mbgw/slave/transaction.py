"""One transaction on the serial line, as its master (slave mode).

A request goes out only after the line has been quiet for t3.5 (or the turnaround delay after
a broadcast).  Every frame that is not the reply -- bad CRC or LRC, another address, another
function, a size the request did not ask for -- is counted and dropped, and we keep listening
until stout has passed, as the spec's master does (Serial Line V1.02, 2.4.1).
"""
import logging
import time
from collections.abc import Callable

from mbgw.config.model import SerialConfig
from mbgw.errors import ChecksumError, LineTimeout
from mbgw.line.frames import reply_matches
from mbgw.line.framing import NO_FORWARD
from mbgw.line.native import Reception
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceStats, DeviceTable
from mbgw.protocol import pdu

wire = logging.getLogger("mbgw.wire")


class SerialMaster:
    def __init__(self, framing, cfg: SerialConfig, counters: Counters, devices: DeviceTable,
                 retries: int = 0, turnaround_ms: int = 100) -> None:
        self.framing = framing
        self.devices = devices
        self._sent_ns = 0
        self._timed_out: DeviceStats | None = None   # whose late reply may still come
        self._counters = counters
        self._retries = retries
        self._nocheck = cfg.nocheck
        self._stout_ns = cfg.stout_ms * 1_000_000
        self._turnaround_us = turnaround_ms * 1000
        self._quiet_from_ns = 0
        self._quiet_us = 0
        self._deadline = 0          # of the reply to the request last sent
        # on_reply(reply PDU, bytes of it forwarded or -1): called before the reply is booked
        self.on_reply: Callable[[bytes, int], None] | None = None
        # The last reply dropped for not answering its request (another function, another
        # size), for a scenario to tell why it failed; its runner clears it.
        self.mismatch: bytes | None = None

    def keep_line_state(self, previous: "SerialMaster") -> None:
        """Taking over the line from previous (new settings): the silence it owes the line
        and the late reply it may still see are owed and seen here too."""
        self._quiet_from_ns = previous._quiet_from_ns
        self._quiet_us = previous._quiet_us
        self._timed_out = previous._timed_out

    @property
    def quiet_until_ns(self) -> int:
        """The line must stay silent until then."""
        return self._quiet_from_ns + self._quiet_us * 1000

    def transact(self, adu: bytes, forward=NO_FORWARD, taken: bool = False,
                 retries: int = -1) -> bytes | None:
        """Send adu (address + PDU) and return the reply PDU; None for a broadcast.
        forward: where the reply may go straight from the C receive (framing.NO_FORWARD);
        taken: the port has exchanged adu already (native.Port.take_request); retries: this
        transaction's own (a scenario's), -1 for the line's.
        Raises LineTimeout when no valid reply came, SerialError when the port failed."""
        device = self.devices.get(adu[0])
        device.transactions += 1
        if adu[0] == pdu.BROADCAST:
            self._await_quiet(adu)
            self._sent(self.framing.send(adu))
            self._counters.broadcasts += 1
            device.broadcasts += 1
            self._quiet_us = self._turnaround_us
            return None
        started = 0
        counters = self._counters
        received = counters.bytes_received - counters.late_bytes   # before the request
        for attempt in range((self._retries if retries < 0 else retries) + 1):
            if attempt:
                self._count(device, "retries")
                taken = False
            if not taken:
                self._await_quiet(adu)
            elif wire.isEnabledFor(logging.DEBUG):
                wire.debug("tx %s", adu.hex(" "))
            got = self._receive(adu, device, forward, taken or (
                self.framing.exchanges(adu) and not self._nocheck), taken)
            if not attempt:
                started = self._sent_ns
            if got is not None and got.frame is not None:
                reply = got.frame[1:]
                if self.on_reply is not None:
                    self.on_reply(reply, got.forwarded)
                ended = got.last_byte_ns
                self._counters.line_busy_ns += ended - started
                exception = reply[1] if reply[0] & pdu.EXCEPTION_FLAG and len(reply) > 1 else None
                if exception is not None:
                    self._counters.device_exceptions += 1
                device.answered((ended - self._sent_ns) / 1e6, exception)
                if self._timed_out is device:
                    self._timed_out = None
                return reply
        self._counters.line_busy_ns += self._deadline - started
        self._count(device, "timeouts")
        device.failed(counters.bytes_received - counters.late_bytes - received)
        self._timed_out = device
        raise LineTimeout()

    def _count(self, device: DeviceStats, name: str) -> None:
        setattr(self._counters, name, getattr(self._counters, name) + 1)
        setattr(device, name, getattr(device, name) + 1)

    def _await_quiet(self, adu: bytes) -> None:
        """Until the line has been quiet long enough for adu to go out."""
        now = time.monotonic_ns()
        if now < self.quiet_until_ns:    # else no C call is needed
            stale = self.framing.port.wait_quiet(self._quiet_from_ns, self._quiet_us)
            if stale:
                self._counters.late_bytes += stale
                self._counters.bytes_received += stale
            now = time.monotonic_ns()
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("tx %s", adu.hex(" "))
        self._sent_ns = now

    def _sent(self, end_ns: int) -> None:
        """The request's last byte leaves the line at end_ns."""
        self._quiet_from_ns = end_ns
        self._quiet_us = self.framing.inter_frame_us
        self._deadline = end_ns + self._stout_ns

    def _receive(self, adu: bytes, device: DeviceStats, forward, exchange: bool,
                 taken: bool = False) -> Reception | None:
        """Send adu (in one C call with the first receive when exchange; taken: that call
        was made already) and return what brought the reply (its frame: address + PDU), or
        None once stout has passed without one."""
        framing = self.framing
        if not exchange:
            self._sent(framing.send(adu))
        while True:
            if exchange:
                exchange = False
                got = framing.exchange(adu, self._stout_ns, forward, taken)
                self._sent(got.request_end_ns)
                if taken:
                    self._sent_ns = got.request_end_ns - (len(adu) + 2) * framing.line.char_ns
            elif self._nocheck:
                got = framing.receive_unchecked(adu, self._deadline)
            else:
                got = framing.receive(adu, self._deadline, forward)
            if got.fault is not None:
                if isinstance(got.fault, LineTimeout):
                    self._quiet_from_ns = max(self._quiet_from_ns, got.last_byte_ns)
                    return None
                self._count(device, "crc_errors" if isinstance(got.fault, ChecksumError)
                            else "invalid_frames")
                self._quiet_from_ns = max(self._quiet_from_ns,
                                          framing.resync(got.last_byte_ns))
                continue
            self._quiet_from_ns = max(self._quiet_from_ns, got.last_byte_ns)
            frame = got.frame
            if frame is None:
                late = self._timed_out
                if late is not None and got.foreign_address == late.address:
                    self._count(late, "late_replies")     # the answer to its timed-out request
                else:
                    self._count(device, "wrong_unit")
                continue
            if self._nocheck:
                return got if len(frame) > 1 else None
            if wire.isEnabledFor(logging.DEBUG):
                wire.debug("rx %s", frame.hex(" "))
            if got.last_byte_ns > self._deadline:
                self._count(device, "late_replies")
                continue
            if not reply_matches(adu[1:], frame[1:]):
                if self._timed_out is device:
                    self._count(device, "late_replies")
                else:
                    self._count(device, "wrong_function")
                    self.mismatch = frame[1:]
                continue
            return got
