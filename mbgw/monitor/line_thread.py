"""A listen-only line's thread (`MonitorLineThread`): one poll() over the tty and a wake-up
eventfd; what the line carries goes to the BusDecoder, the pairs it finds to the MapStore.
Nothing is ever written to the tty, and the port is opened so that the transmitter stays
off: RS-485 in the kernel's mode (RTS at its receive level, raised only for a write, which
never comes), RTS held low otherwise.  Timing is poll()'s milliseconds: the line's t3.5
ends a frame whose length no rule gives, and a late wake-up only lengthens it."""
import dataclasses
import math
import os
import select
import time

from mbgw.config.lines import LineConfig
from mbgw.line.serial_line import SerialLine, read_tty
from mbgw.line.supervisor import TURN_MARGIN_S, LineThread
from mbgw.monitor.bus import MonitorCounters, decoder_for
from mbgw.monitor.store import MapStore
from mbgw.ops.eventfd import drain
from mbgw.ops.status import settings_row
from mbgw.ops.trace import Outcome

_IN = select.POLLIN


def listening(line: LineConfig) -> LineConfig:
    """The line's settings as a listener opens its port: its transmitter never keyed, DTR
    and RTS lowered as soon as it is open (csrc/tty.c mbgw_tty_lock)."""
    serial = line.serial
    if not serial.interface.drives_rts:    # nor RTS/CTS flow control, which would raise it
        serial = dataclasses.replace(serial, rts="low",
                                     cts="ignore" if serial.rts == "flow" else serial.cts)
    return dataclasses.replace(line, serial=dataclasses.replace(serial, dtr="low"))


def transmitter_off(line: SerialLine) -> SerialLine:
    """line, its RTS low where mbgw would drive it for a write (an RS-485 port without the
    kernel's mode: the kernel raised RTS when the port opened, and nothing would lower it)."""
    if line.rts_control:
        line.port.set_modem_lines(None, False)
    return line


class MonitorLineThread(LineThread[LineConfig]):
    def __init__(self, cfg: LineConfig, line: SerialLine | None, store: MapStore,
                 trace) -> None:
        """trace: the line's way into the trace hub (mbgw.ops.trace.LineTrace)."""
        self.counters = MonitorCounters()
        super().__init__(cfg, line)
        self.name_line(cfg.name)
        self.store = store
        self.trace = trace
        serial = cfg.serial
        self.decoder = decoder_for(serial.protocol, self.counters, self._answered, self._heard)
        # a frame begun ends when the line has been quiet this long: t3.5 (RTU), the
        # inter-character timeout (ASCII)
        self._quiet_s = serial.ascii_timeout_ms / 1000 if serial.protocol == "ascii" \
            else serial.t35_us / 1e6
        self._poll = select.poll()
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._poll.register(self._wake_fd, _IN)
        self._tty_fd = -1
        self._quiet_at: float | None = None     # monotonic: the frame begun ends here
        if line is not None:
            self._attach(line)

    @property
    def device(self) -> str:
        return self._cfg.serial.device

    @property
    def settings(self) -> LineConfig:
        return self._cfg

    def use_maps(self, store: MapStore) -> None:
        """New maps (a reload; any thread): the next pair heard is stored under them."""
        self.store = store

    def _answered(self, request: bytes, reply: bytes) -> None:
        self.store.answered(request, reply)

    @property
    def turn_limit_s(self) -> float:
        return self._quiet_s + TURN_MARGIN_S

    def _open_line(self) -> SerialLine:
        return transmitter_off(SerialLine(self._cfg.serial, self.counters))

    def _attach(self, line: SerialLine) -> None:
        self._tty_fd = line.port.fd
        self._poll.register(self._tty_fd, _IN)

    def _detach(self) -> None:
        if self._tty_fd >= 0:
            self._poll.unregister(self._tty_fd)
            self._tty_fd = -1
        self.decoder.quiet()
        self._quiet_at = None

    def _wake(self) -> None:
        os.eventfd_write(self._wake_fd, 1)

    def _turn(self) -> None:
        timeout_ms = self.idle_ms if self._quiet_at is None else \
            max(0, math.ceil((self._quiet_at - time.monotonic()) * 1000))
        for fd, events in self._poll.poll(timeout_ms):
            if fd == self._tty_fd:
                self._read(events)
            else:
                drain(fd)
        if self._quiet_at is not None and time.monotonic() >= self._quiet_at:
            self._quiet_at = None
            self.decoder.quiet()

    def _while_down(self, timeout_s: float) -> None:
        for fd, _ in self._poll.poll(int(timeout_s * 1000)):
            drain(fd)

    def _read(self, events: int) -> None:
        data = read_tty(self._tty_fd, events)
        if not data:
            return
        self.counters.bytes_received += len(data)
        self.decoder.feed(data)
        self._quiet_at = time.monotonic() + self._quiet_s if self.decoder.pending else None

    def _heard(self, adu: bytes, what: str) -> None:
        if self.trace.active:
            self.trace.emit_threadsafe(_event(adu, what))

    def status(self) -> dict:
        """Its row of the status's "lines" (any thread)."""
        c = self.counters.snapshot()
        ages = self.store.ages(time.monotonic())
        return {"name": self.line_name, "device": self._cfg.serial.device, "mode": "monitor",
                "state": self.state, "state_since": self.state_since,
                "settings": settings_row(self._cfg),
                "requests": c["monitor_answered"] + c["monitor_unanswered"],
                "replies": c["monitor_answered"], "timeouts": c["monitor_unanswered"],
                "counters": c, "devices": [],
                "maps": [{"map": index, "age_s": None if age is None else round(age, 3)}
                         for index, age in sorted(ages.items())]}

    def _finish(self) -> None:
        super()._finish()
        os.close(self._wake_fd)


def _event(adu: bytes, what: str) -> dict:
    """A frame heard, as `mbgw trace` shows it: the bus's own request or reply."""
    direction = {"reply": "reply", "unanswered": "no reply", "crc error": "ignored"}.get(
        what, "request")
    return {"time": time.time(), "mode": "monitor", "direction": direction,
            "address": adu[0] if adu else None, "function": adu[1] if len(adu) > 1 else 0,
            "length": max(len(adu) - 1, 0), "pdu": adu[1:].hex(), "tid": None, "unit": None,
            "outcome": {"reply": Outcome.REPLY, "unanswered": Outcome.TIMEOUT,
                        "crc error": Outcome.CRC_ERROR}.get(what, ""),
            "latency_ms": None, "server": None, "peer": None, "local": None, "remote": None}
