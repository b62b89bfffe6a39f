"""The request/reply pairs of a bus mbgw only listens to (RTU), with no I/O: bytes in,
frames out.  A frame ends where its length says (native.rtu_request_length and
rtu_reply_length, the C core's rules) or, for a function whose length no rule gives, when the
line falls quiet (`quiet`).  A frame after a request, from its address, that answers it
(native.reply_matches) is its reply; a request followed by anything else was not answered
(a broadcast is never answered and never counted so)."""
import dataclasses
from collections.abc import Callable

from mbgw.line import native

CRC_LEN = 2
BROADCAST = 0


@dataclasses.dataclass(slots=True)
class MonitorCounters:
    """What a monitor line counts; bytes_received etc. are what SerialLine counts itself."""
    bytes_sent: int = 0
    bytes_received: int = 0
    noise_bytes: int = 0
    echo_errors: int = 0
    monitor_frames: int = 0
    monitor_crc_errors: int = 0
    monitor_unanswered: int = 0
    monitor_answered: int = 0

    def snapshot(self) -> dict[str, int]:
        return {"bytes_received": self.bytes_received,
                "monitor_frames": self.monitor_frames,
                "monitor_crc_errors": self.monitor_crc_errors,
                "monitor_unanswered": self.monitor_unanswered,
                "monitor_answered": self.monitor_answered}


# what a BusDecoder hands its owner: a request ADU and the reply ADU that answers it, both
# without their CRC
Answered = Callable[[bytes, bytes], None]


class BusDecoder:
    def __init__(self, counters: MonitorCounters, answered: Answered,
                 heard: Callable[[bytes, str], None] | None = None) -> None:
        """answered(request, reply): a pair; heard(adu, what): every frame, for the trace
        (what: "request", "reply", "unanswered", "crc error")."""
        self.counters = counters
        self._answered = answered
        self._heard = heard
        self._buf = bytearray()
        self._request: bytes | None = None     # the last request, while its reply may come

    @property
    def pending(self) -> bool:
        """Bytes of a frame not ended yet."""
        return bool(self._buf)

    def feed(self, data: bytes) -> None:
        self._buf += data
        while self._buf and self._take():
            pass

    def quiet(self) -> None:
        """The line has been quiet for t3.5: what was received is one frame (or noise)."""
        if self._buf:
            wire = bytes(self._buf)
            self._buf.clear()
            if _checks(wire):
                self._frame(wire[:-CRC_LEN], self._could_be_reply(wire))
            else:
                self._bad(wire)

    def _could_be_reply(self, buf: bytes) -> bool:
        req = self._request
        return req is not None and len(buf) >= 2 and buf[0] == req[0] and \
            buf[1] & 0x7F == req[1]

    def _take(self) -> bool:
        """Cut one frame off the buffer when its length is known and there; False: wait.  A
        frame from the address of the request asked may be its reply or the master's next
        request (a retry): whichever length checks is the frame."""
        buf = bytes(self._buf)
        lengths = []
        if self._could_be_reply(buf):
            assert self._request is not None
            lengths.append((native.rtu_reply_length(len(self._request), buf), True))
        lengths.append((native.rtu_request_length(buf), False))
        waiting = False
        for length, is_reply in lengths:
            if length <= 0 or length > len(buf):
                waiting = True          # more to come, or a length only silence tells
            elif _checks(buf[:length]):
                del self._buf[:length]
                self._frame(buf[:length - CRC_LEN], is_reply)
                return True
        if waiting:
            return False
        length = lengths[0][0]
        del self._buf[:length]
        self._bad(buf[:length])
        return True

    def _bad(self, wire: bytes) -> None:
        self.counters.monitor_crc_errors += 1
        self._tell(wire, "crc error")

    def _frame(self, adu: bytes, is_reply: bool) -> None:
        self.counters.monitor_frames += 1
        request = self._request
        if is_reply and request is not None and native.reply_matches(request[1:], adu[1:]):
            self._request = None
            self.counters.monitor_answered += 1
            self._tell(adu, "reply")
            self._answered(request, adu)
            return
        self._given_up()
        self._request = adu if adu[0] != BROADCAST else None
        self._tell(adu, "request")

    def _given_up(self) -> None:
        if self._request is not None:
            self.counters.monitor_unanswered += 1
            self._tell(self._request, "unanswered")
            self._request = None

    def _tell(self, adu: bytes, what: str) -> None:
        if self._heard is not None:
            self._heard(adu, what)


def _checks(wire: bytes) -> bool:
    return len(wire) >= 4 and \
        native.crc16(wire[:-CRC_LEN]) == int.from_bytes(wire[-CRC_LEN:], "little")
