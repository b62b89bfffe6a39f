"""The bus work of commissioning (mbgw scan, mbgw probe): one request at a time to one
address on a line no gateway uses, its reply timed, the port's baud rate and format changed
between settings."""
import time
from typing import TYPE_CHECKING, NamedTuple

from mbgw.errors import LineTimeout
from mbgw.line.serial_line import SerialLine

if TYPE_CHECKING:      # the settings' type only: the line never reads the configuration files
    from mbgw.config.model import SerialConfig

# the harmless read: FC 3, holding register 0, quantity 1
READ_REGISTER_0 = bytes((0x03, 0x00, 0x00, 0x00, 0x01))
# FC 43/14 Read Device Identification, read code 01 (basic objects) from object 0
READ_BASIC_IDENTITY = bytes((0x2B, 0x0E, 0x01, 0x00))
REPORT_SERVER_ID = bytes((0x11,))


class Answer(NamedTuple):
    pdu: bytes              # the reply's PDU (an exception reply too)
    response_ns: int        # from the request's last byte to the reply's last byte


class Bus:
    """A serial line opened for commissioning; one request in flight at a time."""

    def __init__(self, cfg: "SerialConfig") -> None:
        self.line = SerialLine(cfg)
        self.port = self.line.port
        self._end_us = cfg.end_of_frame_us
        self.port.set_byte_timeout(self._end_us)
        self._quiet_us = cfg.t35_us
        # a unit that did not answer in time -> until when its late reply may still come
        self._late_until: dict[int, int] = {}

    def tune(self, cfg: "SerialConfig") -> None:
        """Go on at cfg's baud rate and format."""
        self.line.retune(cfg)
        self._end_us = cfg.end_of_frame_us
        self.port.set_byte_timeout(self._end_us)
        self._quiet_us = cfg.t35_us

    def ask(self, unit: int, pdu: bytes, timeout_ms: int) -> Answer | None:
        """Send pdu to unit; its reply, or None when none came within timeout_ms
        (ask_once).  After a unit missed its timeout, its next request waits for its late
        reply (_sit_out_late_reply)."""
        self._sit_out_late_reply(unit)
        started_ns = time.monotonic_ns()
        answer = ask_once(self.line, unit, pdu, timeout_ms, self._quiet_us)
        if answer is None:
            self._late_until[unit] = started_ns + 2 * timeout_ms * 1_000_000
        return answer

    def _sit_out_late_reply(self, unit: int) -> None:
        """RTU has no transaction id: a unit asked again after it did not answer in time could
        hand its late reply to the new request.  Whatever the bus carries during the timeout
        after the one missed (at most as long again) is skipped before unit is asked again."""
        until = self._late_until.pop(unit, 0)
        while time.monotonic_ns() < until:
            self.port.read_reply(until, self._end_us)

    def close(self) -> None:
        self.line.close()


def ask_once(line: SerialLine, unit: int, pdu: bytes, timeout_ms: int,
             quiet_us: int) -> Answer | None:
    """Send pdu to unit on line (RTU, its port's end-of-frame silence set) after quiet_us of
    quiet; its reply, or None when none came within timeout_ms of the request's start (its
    sending included, so that n requests to silent units take at most n × timeout_ms).  A
    late reply from another unit, noise and broken frames are skipped while the time lasts.
    Also the running daemon's survey read, on the line's own thread."""
    adu = bytes((unit,)) + pdu
    port = line.port
    start_ns = time.monotonic_ns()
    deadline_ns = start_ns + timeout_ms * 1_000_000
    # bytes still coming (noise, a reply to someone else) are skipped, never taken for this
    # request's reply
    port.wait_quiet(start_ns, quiet_us)
    sent_ns = line.transmit_rtu(adu)
    while True:
        got = port.receive_reply(adu, deadline_ns)
        if got.frame is not None:
            return Answer(got.frame[1:], max(0, got.last_byte_ns - sent_ns))
        if isinstance(got.fault, LineTimeout) or time.monotonic_ns() >= deadline_ns:
            return None
