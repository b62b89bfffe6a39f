"""The request/reply pairs of a bus mbgw only listens to, with no I/O: bytes in, frames out.
RTU (BusDecoder): a frame ends where its length says (native.rtu_request_length and
rtu_reply_length, the C core's rules) or, for a function whose length no rule gives, when the
line falls quiet (`quiet`).  ASCII (AsciiBusDecoder): a frame is ':' to CR LF, its LRC
checked (a wrong one counts as a CRC error).  A frame after a request, from its address,
that answers it (native.reply_matches) is its reply; a request followed by anything else
was not answered (a broadcast is never answered and never counted so)."""
import dataclasses
from collections.abc import Callable

from mbgw.errors import ChecksumError, FrameError
from mbgw.line import native
from mbgw.line.serial_line import LineCounts

CRC_LEN = 2
BROADCAST = 0


@dataclasses.dataclass(slots=True)
class MonitorCounters(LineCounts):
    """What a monitor line counts: what SerialLine counts itself (LineCounts), and these."""
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


class AsciiBusDecoder(BusDecoder):
    """The same pairs on an ASCII bus: each frame ':' to CR LF.  What comes outside a frame
    is noise; a frame that a new ':' or the line's quiet (the inter-character timeout) cuts
    short, or whose LRC is wrong, counts as a CRC error."""

    def feed(self, data: bytes) -> None:
        buf = self._buf
        buf += data
        while buf:
            start = buf.find(b":")
            if start < 0:
                self.counters.noise_bytes += len(buf)
                buf.clear()
                return
            if start:
                self.counters.noise_bytes += start
                del buf[:start]
            end = buf.find(b"\r\n")
            cut = buf.find(b":", 1, end if end >= 0 else len(buf))
            if cut > 0:                 # a frame begun again before this one ended
                self._bad(bytes(buf[:cut]))
                del buf[:cut]
                continue
            if end < 0:
                if len(buf) > native.ASCII_MAX_FRAME:
                    self._bad(bytes(buf))
                    buf.clear()
                return
            wire = bytes(buf[:end + 2])
            del buf[:end + 2]
            self._ascii_frame(wire)

    def quiet(self) -> None:
        """The inter-character timeout has passed: a frame begun is cut short."""
        if self._buf:
            self._bad(bytes(self._buf))
            self._buf.clear()

    def _ascii_frame(self, wire: bytes) -> None:
        try:
            adu = native.ascii_decode(wire)
        except (ChecksumError, FrameError):
            self._bad(wire)
            return
        if len(adu) < 2:
            self._bad(wire)
            return
        self._frame(adu, self._could_be_reply(adu))


def decoder_for(protocol: str, counters: MonitorCounters, answered: Answered,
                heard: Callable[[bytes, str], None] | None = None) -> BusDecoder:
    """The decoder of a line of this protocol ("rtu" or "ascii")."""
    kind = AsciiBusDecoder if protocol == "ascii" else BusDecoder
    return kind(counters, answered, heard)


def _checks(wire: bytes) -> bool:
    return len(wire) >= 4 and \
        native.crc16(wire[:-CRC_LEN]) == int.from_bytes(wire[-CRC_LEN:], "little")
