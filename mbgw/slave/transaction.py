"""One transaction on the serial line, as its master (slave mode).

A request goes out only after the line has been quiet for t3.5 and the interframe silence
(VPGate's, 0 by default), or the turnaround delay after a broadcast.  Every frame that is not
the reply -- bad CRC or LRC, another address, another function, a size the request did not
ask for -- is counted and dropped, and we keep listening until stout has passed, as the
spec's master does (Serial Line V1.02, 2.4.1).

The late window.  A slave may answer after stout (a radio link, a slow device, a stout set
too low), and its late answer looks just like the answer to the next request to the same
address, a read of the same size above all.  So after a transaction in which a try timed
out, the address has a late window: no request goes to it (held(); the scheduler serves
other addresses meanwhile, the C shortcut reads late_until) until each try that timed out has
had its late reply -- dropped and counted late_replies -- or the line has been quiet for
late-window past the last try's deadline.  While no request to the address is on the line,
any frame from it is such a late reply.  The retries of a request are the same request: they
go at once, and a late reply to an earlier try that comes during a retry answers it.

The line's framing (mbgw.slave.framing: how a frame looks on the line) sends an ADU
(address + PDU) and receives one, checked.
"""
import logging
import time
from array import array
from collections.abc import Callable

from mbgw.config.model import SerialConfig
from mbgw.errors import ChecksumError, LineTimeout
from mbgw.line.native import NO_FORWARD, Forward, Reception, reply_matches
from mbgw.line.supervisor import longest_frame_s
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth, DeviceStats
from mbgw.protocol import pdu
from mbgw.slave.device_timing import DeviceTiming

wire = logging.getLogger("mbgw.wire")

# What hear() receives after: address 0 (broadcast), which no reply carries, so every frame
# is another address's.
LISTENING = b"\x00\x00"


class SerialMaster:
    def __init__(self, framing, cfg: SerialConfig, counters: Counters, devices: DeviceHealth,
                 retries: int = 0, turnaround_ms: int = 100, late_window_ms: int = 0,
                 timing: DeviceTiming | None = None) -> None:
        """timing: stout, retries, pause and late window by address (None: the line's,
        from cfg, retries and late_window_ms, for every address)."""
        self.framing = framing
        self.devices = devices
        self._sent_ns = 0
        if timing is None:
            timing = DeviceTiming(cfg.stout_ms, retries, late_window_ms)
        self._late_window_ns = timing.late_window_ns
        self._stouts_ns = timing.stout_ns
        self._retries = timing.retries
        self._pauses_us = timing.pause_us
        # a frame that has begun is whole within this (its longest, and the silence after)
        self._frame_ns = int(longest_frame_s(cfg) * 1e9) + cfg.end_of_frame_us * 1000
        # By address: when its late window ends (CLOCK_MONOTONIC ns, 0: none open; C's
        # shortcut reads it in place), and the late replies it may still bring.
        self.late_until = array("q", bytes(8 * 256))
        self._late_pending = bytearray(256)
        self.late_open: set[int] = set()        # the addresses with a window open
        self._counters = counters
        self._nocheck = cfg.nocheck
        self._stout_ns = cfg.stout_ms * 1_000_000
        self._turnaround_us = turnaround_ms * 1000
        self._interframe_us = cfg.interframe_ms * 1000
        self._quiet_from_ns = 0
        self._quiet_us = 0
        self._deadline = 0          # of the reply to the request last sent
        # on_late(frame: address + PDU): a late reply was dropped (for the trace)
        self.on_late: Callable[[bytes], None] | None = None
        # on_retry(): called before each repeat of a request (a scenario's status says so)
        self.on_retry: Callable[[], None] | None = None
        # The transaction under way, for book() and LineTimeout: its device, when its first
        # try began, its tries but one, the bytes in frames that were not the reply, and the
        # last reply dropped for not answering it (another function, another size).
        self._device: DeviceStats | None = None
        self._address = 0
        self._adu = b""
        self._started = 0
        self._attempt = 0
        self._bad_bytes = 0
        self._mismatch: bytes | None = None
        self._taken: Reception | None = None    # book_taken's, for the next exchange()

    def keep_line_state(self, previous: "SerialMaster") -> None:
        """Taking over the line from previous (new settings): the silence it owes the line
        and the late reply it may still see are owed and seen here too."""
        self._quiet_from_ns = previous._quiet_from_ns
        self._quiet_us = previous._quiet_us
        self.late_until = previous.late_until
        self._late_pending = previous._late_pending
        self.late_open = previous.late_open

    @property
    def quiet_until_ns(self) -> int:
        """The line must stay silent until then."""
        return self._quiet_from_ns + self._quiet_us * 1000

    def transact(self, adu: bytes, retries: int = -1, stout_ns: int = 0) -> bytes | None:
        """exchange(adu) and book() its reply: the reply PDU, None for a broadcast."""
        got = self.exchange(adu, NO_FORWARD, retries, stout_ns)
        if got is None:
            return None
        self.book(got)
        frame = got.frame
        assert frame is not None        # exchange() returns replies only
        return frame[1:]

    def book_taken(self, got: Reception) -> None:
        """The port's shortcut (native.Port.take_request) has exchanged a request already
        and got is what it received: the next exchange() of that request goes on from
        there, without sending it."""
        self._taken = got

    def exchange(self, adu: bytes, forward: Forward = NO_FORWARD,
                 retries: int = -1, stout_ns: int = 0) -> Reception | None:
        """Send adu (address + PDU) and return what brought the reply (its frame: address
        + PDU; forwarded: the bytes of it forward's client has had already), for book()
        once the reply has gone on; None for a broadcast (booked already).  forward: where
        the reply may go straight from the C receive; retries: this transaction's own (a
        scenario's), -1 for the line's; stout_ns: this one's stout (a probe's), 0 for the
        address's.  Raises LineTimeout (booked; its mismatch: the last
        reply that did not answer adu) when no valid reply came, SerialError when the port
        failed."""
        taken, self._taken = self._taken, None
        self._address = adu[0]
        self._adu = adu
        self._stout_ns = stout_ns or self._stouts_ns[adu[0]]
        self._device = device = self.devices.get(adu[0])
        device.transactions += 1
        if adu[0] == pdu.BROADCAST:
            self._await_quiet(adu)
            self._sent(self.framing.send(adu))
            self._counters.broadcasts += 1
            device.broadcasts += 1
            self._quiet_us = self._turnaround_us
            return None
        if self.late_until[adu[0]]:
            self._await_late(adu[0])
        counters = self._counters
        noise = counters.noise_bytes      # from here on, bytes in no frame ...
        self._bad_bytes = 0               # ... and in frames that were not the reply
        self._mismatch = None
        for attempt in range((self._retries[adu[0]] if retries < 0 else retries) + 1):
            if attempt:
                self._count(device, "retries")
                taken = None
                if self.on_retry is not None:
                    self.on_retry()
            if taken is None:
                self._await_quiet(adu)
            elif wire.isEnabledFor(logging.DEBUG):
                wire.debug("tx %s", adu.hex(" "))
            got = self._receive(adu, device, forward, taken is not None or (
                self.framing.exchanges(adu) and not self._nocheck), taken)
            if not attempt:
                self._started = self._sent_ns
            if got is not None and got.frame is not None:
                self._attempt = attempt
                return got
        self._counters.line_busy_ns += self._deadline - self._started
        self._count(device, "timeouts")
        if not device.first_timeout_seen:      # its probe, until a request is answered
            device.first_timeout_seen = True
            if device.probe_adu is None and pdu.READ_ONLY[adu[1]]:
                device.probe_adu = adu
        device.failed(counters.noise_bytes - noise + self._bad_bytes, self._stout_ns / 1e6)
        self._open_window(adu[0], attempt + 1)
        raise LineTimeout(self._mismatch)

    def book(self, got: Reception) -> None:
        """The books of the reply exchange() has just returned (got), kept once the reply
        has gone on: the line's busy time, the device's answer and latency, and the late
        window the tries before it may have left open."""
        frame = got.frame
        device = self._device
        assert frame is not None and device is not None
        ended = got.last_byte_ns
        self._counters.line_busy_ns += ended - self._started
        exception = frame[2] if frame[1] & pdu.EXCEPTION_FLAG and len(frame) > 2 else None
        if exception is not None:
            self._counters.device_exceptions += 1
        device.answered((ended - self._sent_ns) / 1e6, exception)
        if pdu.READ_ONLY[self._adu[1]]:     # its probe from now on (DeviceStats.probe_adu)
            device.probe_adu = self._adu
        if self._attempt:           # the tries before may still answer
            self._open_window(self._address, self._attempt)

    # --- the late window (see the module's docstring) ---

    def held(self, address: int) -> bool:
        """A request to address must wait: its late window is open."""
        until = self.late_until[address]
        if not until:
            return False
        if time.monotonic_ns() < until:
            return True
        self._close_window(address)
        return False

    def next_window_end_ns(self) -> int:
        """When the first late window open ends (0: none is)."""
        return min((self.late_until[a] for a in self.late_open), default=0)

    def _open_window(self, address: int, tries: int) -> None:
        window_ns = self._late_window_ns[address]
        if not window_ns:
            return
        self.late_until[address] = self._deadline + window_ns
        self._late_pending[address] = min(tries, 255)
        self.late_open.add(address)

    def _close_window(self, address: int) -> None:
        self.late_until[address] = 0
        self._late_pending[address] = 0
        self.late_open.discard(address)

    def _late_reply(self, frame: bytes) -> bool:
        """frame (address + PDU) is a late reply its address's window waits for: counted,
        and the window closes when every try has had its own."""
        if not frame or not self._late_pending[frame[0]]:
            return False
        address = frame[0]
        self._count(self.devices.get(address), "late_replies")
        self._late_pending[address] -= 1
        if not self._late_pending[address]:
            self._close_window(address)
        if self.on_late is not None:
            self.on_late(frame)
        return True

    def _await_late(self, address: int) -> None:
        """Listen until address's late window closes (a scenario's request, which the
        scheduler cannot hold back)."""
        while self.held(address):
            self.hear(self.late_until[address])

    def hear(self, deadline_ns: int = 0) -> None:
        """A frame nobody asked for (the line is idle; deadline_ns: wait for its first byte
        until then, else it has begun): a late reply that an address's window waits for
        (counted late_replies, see _late_reply), or an unsolicited frame."""
        framing = self.framing
        counters = self._counters
        deadline_ns = deadline_ns or time.monotonic_ns() + self._frame_ns
        if self._nocheck:
            got = framing.receive_unchecked(LISTENING, deadline_ns)
        else:
            got = framing.receive(LISTENING, deadline_ns)
        if isinstance(got.fault, LineTimeout):
            return
        last = got.last_byte_ns
        if got.fault is not None:
            last = framing.resync(last)
        self._quiet_from_ns = max(self._quiet_from_ns, last)
        if self._nocheck or got.fault is not None:
            counters.unsolicited_frames += 1
            counters.unsolicited_bytes += got.length + got.noise
            return
        frame = got.frame if got.frame is not None else got.foreign
        if not self._late_reply(frame):
            counters.unsolicited_frames += 1
            counters.unsolicited_bytes += got.length

    def _count(self, device: DeviceStats, name: str) -> None:
        setattr(self._counters, name, getattr(self._counters, name) + 1)
        setattr(device, name, getattr(device, name) + 1)

    def _await_quiet(self, adu: bytes) -> None:
        """Until the line has been quiet long enough for adu to go out: what it owes the line
        and the pause adu's device wants before each of its frames."""
        now = time.monotonic_ns()
        quiet_us = max(self._quiet_us, self._pauses_us[adu[0]])
        if now < self._quiet_from_ns + quiet_us * 1000:    # else no C call is needed
            stale = self.framing.port.wait_quiet(self._quiet_from_ns, quiet_us)
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
        self._quiet_us = self.framing.inter_frame_us + self._interframe_us
        self._deadline = end_ns + self._stout_ns

    def _receive(self, adu: bytes, device: DeviceStats, forward: Forward, exchange: bool,
                 taken: Reception | None = None) -> Reception | None:
        """Send adu (in one C call with the first receive when exchange; taken: that call
        was made already, by the shortcut, and received this) and return what brought the
        reply (its frame: address + PDU), or None once stout has passed without one."""
        framing = self.framing
        if not exchange:
            self._sent(framing.send(adu))
        while True:
            got = self._reception(adu, forward, exchange, taken)
            exchange, taken = False, None
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
                if not self._late_reply(got.foreign):
                    self._count(device, "wrong_unit")
                    self._bad_bytes += got.length
                continue
            if self._nocheck:
                return got if len(frame) > 1 else None
            if wire.isEnabledFor(logging.DEBUG):
                wire.debug("rx %s", frame.hex(" "))
            if got.last_byte_ns > self._deadline:
                self._count(device, "late_replies")
                continue
            if not reply_matches(adu[1:], frame[1:]):
                self._count(device, "wrong_function")
                self._bad_bytes += got.length
                self._mismatch = frame[1:]
                continue
            return got

    def _reception(self, adu: bytes, forward: Forward, exchange: bool,
                   taken: Reception | None) -> Reception:
        """The next frame (or fault) on the line for adu; exchange: adu is sent first, in
        the same C call (taken: that call was made already, by the shortcut)."""
        framing = self.framing
        if exchange:
            if taken is None:
                got = framing.exchange(adu, self._stout_ns, forward)
                self._sent(got.request_end_ns)
                return got
            got = framing.exchanged(adu, taken)
            self._sent(got.request_end_ns)
            self._sent_ns = got.request_end_ns - (len(adu) + 2) * framing.line.char_ns
            return got
        if self._nocheck:
            return framing.receive_unchecked(adu, self._deadline)
        return framing.receive(adu, self._deadline, forward)
