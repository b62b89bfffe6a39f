"""Transparent mode's line thread (`TransparentLineThread`): one poll() over the tty, the tx
area's watch, the raw port and a wake-up eventfd.  Frames from the line are stored at
rx-address and given to the raw client; the tx area's frames and the raw client's bytes are
sent once `silence` has passed since the line's last received byte.  Timing is poll()'s
milliseconds: eof-timeout and silence are whole ms, and a pause of the line thread only
lengthens them."""
import collections
import logging
import math
import os
import select
import time

from mbgw.config.transparent import TransparentModeConfig
from mbgw.line.serial_line import SerialLine, read_tty
from mbgw.line.supervisor import TURN_MARGIN_S, LineThread
from mbgw.ops.eventfd import drain
from mbgw.ops.trace import TraceHub
from mbgw.transparent.counters import TransparentCounters
from mbgw.transparent.frames import MAX_FRAME, Receiver, Rules, from_registers
from mbgw.transparent.raw import RECEIVE_SIZE, RawPort

log = logging.getLogger("mbgw.transparent")

_IN = select.POLLIN


class TransparentLineThread(LineThread[TransparentModeConfig]):
    def __init__(self, cfg: TransparentModeConfig, line: SerialLine | None, table,
                 raw: RawPort | None, counters: TransparentCounters) -> None:
        self.counters = counters
        super().__init__(cfg, line)
        self.trace = TraceHub()
        self._table = table
        self._raw = raw
        self._poll = select.poll()
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._tx_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._poll.register(self._wake_fd, _IN)
        self._poll.register(self._tx_fd, _IN)
        if raw is not None:
            raw.attach(self._poll)
        self._tty_fd = -1
        self._outgoing: collections.deque[tuple[bytes, bool]] = collections.deque()
        self._quiet_from = 0.0         # monotonic: the line's last received byte
        self._frame_deadline: float | None = None
        self._rx_counter = 0
        self._watch = -1
        self._take_rules(cfg)
        if line is not None:
            self._attach(line)
        else:
            self._detach()

    # --- the settings ---

    def _take_rules(self, cfg: TransparentModeConfig) -> None:
        self._rules = rules = Rules(cfg.transparent, cfg.serial)
        self._receiver = Receiver(rules)
        self._frame_deadline = None
        t = cfg.transparent
        if self._watch >= 0:
            self._table.unwatch(self._watch)
        self._watch = self._table.watch(t.tx_address, rules.tx_registers, self._tx_fd)
        area = from_registers(self._table.read(t.tx_address, rules.tx_registers), t.tx_size)
        self._tx_counter: int | None = area[0] if t.trigger else None

    def _configure(self, old: TransparentModeConfig, reopen: bool) -> None:
        if self._cfg.transparent != old.transparent or self._cfg.serial != old.serial:
            self._take_rules(self._cfg)

    @property
    def turn_limit_s(self) -> float:
        """The longest send (what the raw client sends in one read) after the silence."""
        s = self._cfg.serial
        return ((max(RECEIVE_SIZE, MAX_FRAME) + 2) * s.char_ns / 1e9
                + (self._cfg.transparent.silence_ms + sum(s.rtsdelays)) / 1000 + TURN_MARGIN_S)

    def _open_line(self) -> SerialLine:
        return SerialLine(self._cfg.serial, self.counters)

    def _attach(self, line: SerialLine) -> None:
        self._tty_fd = line.port.fd
        self._poll.register(self._tty_fd, _IN)
        self._table.set_flags(line_down=False)

    def _detach(self) -> None:
        if self._tty_fd >= 0:
            self._poll.unregister(self._tty_fd)
            self._tty_fd = -1
        self._receiver.pending.clear()
        self._frame_deadline = None
        self._table.set_flags(line_down=True)

    # --- the loop ---

    def _wake(self) -> None:
        os.eventfd_write(self._wake_fd, 1)

    def _turn(self) -> None:
        for fd, events in self._poll.poll(self._timeout_ms()):
            self._ready(fd, events)
        now = time.monotonic()
        if self._frame_deadline is not None and now >= self._frame_deadline:
            self._line_quiet()
        if self._outgoing and now >= self._quiet_from + self._cfg.transparent.silence_ms / 1000:
            self._send_all()
        if self._raw is not None and self._raw.resting_until is not None:
            self._raw.wake_up(now)

    def _while_down(self, timeout_s: float) -> None:
        for fd, events in self._poll.poll(int(timeout_s * 1000)):
            self._ready(fd, events)
        self._outgoing.clear()          # nothing waits for a line that is not there
        if self._raw is not None and self._raw.resting_until is not None:
            self._raw.wake_up(time.monotonic())

    def _timeout_ms(self) -> int:
        deadlines = []
        if self._frame_deadline is not None:
            deadlines.append(self._frame_deadline)
        if self._outgoing:
            deadlines.append(self._quiet_from + self._cfg.transparent.silence_ms / 1000)
        if self._raw is not None and self._raw.resting_until is not None:
            deadlines.append(self._raw.resting_until)
        if not deadlines:
            return self.idle_ms
        return max(0, math.ceil((min(deadlines) - time.monotonic()) * 1000))

    def _ready(self, fd: int, events: int) -> None:
        raw = self._raw
        if fd == self._tty_fd:
            self._read_line(events)
        elif fd == self._tx_fd:
            drain(fd)
            self._take_tx()
        elif fd == self._wake_fd:
            drain(fd)
        elif raw is not None and fd in raw.listeners:
            raw.accept(fd)
        elif raw is not None and raw.is_client(fd):
            if raw.reading:
                self._read_raw(raw)
            else:
                raw.ended()

    # --- receiving ---

    def _read_line(self, events: int) -> None:
        data = read_tty(self._tty_fd, events)
        if not data:
            return
        now = time.monotonic()
        self.counters.bytes_received += len(data)
        self._quiet_from = now
        frames, overflow = self._receiver.feed(data)
        for wire in frames:
            self._received(wire)
        if overflow:
            self._incomplete(b"", "overflow")
        pending = bool(self._receiver.pending)
        self._frame_deadline = now + self._rules.eof_timeout_ms / 1000 if pending else None

    def _line_quiet(self) -> None:
        self._frame_deadline = None
        partial = bytes(self._receiver.pending)
        wire = self._receiver.quiet()
        if wire is None:
            self._incomplete(partial, "incomplete")
        elif wire:
            self._received(wire)

    def _incomplete(self, partial: bytes, outcome: str) -> None:
        self.counters.frames_incomplete += 1
        if self.trace.active:
            self._emit("rx", partial, outcome)

    def _received(self, wire: bytes) -> None:
        c = self.counters
        c.frames_received += 1
        payload = self._rules.payload(wire)
        if payload is None:
            c.crc_errors += 1
            if self.trace.active:
                self._emit("rx", wire, "crc error")
            return
        if self._rules.trigger:
            self._rx_counter = (self._rx_counter + 1) & 0xFF
        registers, truncated = self._rules.rx_area(payload, self._rx_counter)
        self._table.write(self._cfg.transparent.rx_address, registers)
        c.frames_stored += 1
        c.frames_truncated += truncated
        if self._raw is not None:
            self._raw.send(wire)
        if self.trace.active:
            self._emit("rx", wire, "truncated" if truncated else "stored")

    # --- sending ---

    def _take_tx(self) -> None:
        rules = self._rules
        values = self._table.take_change(self._watch, rules.tx_registers)
        if values is None:
            return
        area = from_registers(values, self._cfg.transparent.tx_size)
        frame, self._tx_counter = rules.tx_frame(area, self._tx_counter)
        if frame is None:
            return
        if not frame:
            self.counters.sends_refused += 1
            if self.trace.active:
                self._emit("tx", area, "refused")
            return
        self._outgoing.append((frame, True))

    def _read_raw(self, raw: RawPort) -> None:
        data = raw.receive()
        if not data:                     # nothing now, or no more (then no longer polled)
            return
        self.counters.raw_bytes_in += len(data)
        self._outgoing.append((data, False))

    def _send_all(self) -> None:
        line = self._line
        assert line is not None
        while self._outgoing:
            frame, from_table = self._outgoing.popleft()
            line.transmit(frame)
            if from_table:
                self.counters.frames_sent += 1
            if self.trace.active:
                self._emit("tx" if from_table else "raw", frame, "sent")

    def _emit(self, direction: str, frame: bytes, outcome: str) -> None:
        self.trace.emit_threadsafe({"time": time.time(), "mode": "transparent", "line": "serial",
                                    "direction": direction, "length": len(frame),
                                    "frame": frame.hex(), "outcome": outcome})

    def _finish(self) -> None:
        super()._finish()
        if self._raw is not None:
            self._raw.close()
        self._table.unwatch(self._watch)
        os.close(self._wake_fd)
        os.close(self._tx_fd)
