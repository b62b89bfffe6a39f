"""The raw line monitor (`mbgw trace --raw`): what the capture (native.Capture) recorded,
as bursts -- the bytes between two silences of at least t3.5, or a direction change -- each
with the silence before it and what it was: a request we sent, the reply to it, noise
(bytes that made no valid reply while one was awaited), or unsolicited (bytes while none
was).  Nothing here runs unless somebody watches."""
import time

from mbgw.line.native import Capture, crc16


class RawMonitor:
    """Bursts for the trace hub, on the line's thread: watch() as the hub says, take() after
    each turn."""

    def __init__(self, char_ns: int, quiet_us: int, stout_ms: int, ascii: bool = False) -> None:
        self._capture: Capture | None = None
        self._answers = False
        self.configure(char_ns, quiet_us, stout_ms, ascii)
        self._last_end_ns: int | None = None
        self._request: bytes | None = None     # the last request, while its reply is awaited
        self._deadline_ns = 0

    def configure(self, char_ns: int, quiet_us: int, stout_ms: int, ascii: bool = False,
                  answers: bool = False) -> None:
        """answers: mbgw is the line's slave (master mode): what it sends are replies, what
        it receives requests (or noise)."""
        self._char_ns = char_ns
        self._quiet_ns = quiet_us * 1000
        self._stout_ns = stout_ms * 1_000_000
        self._ascii = ascii
        self._answers = answers

    @property
    def watching(self) -> bool:
        return self._capture is not None and self._capture.on

    def watch(self, on: bool) -> None:
        if on == self.watching:
            return
        if on:
            if self._capture is None:
                self._capture = Capture()
            self._last_end_ns = None
            self._request = None
            self._capture.start()
        elif self._capture is not None:
            self._capture.stop()

    def take(self) -> list[dict]:
        """The bursts captured since the last take, as trace events."""
        if self._capture is None:
            return []
        records, dropped = self._capture.take()
        events = self.events(records)
        if dropped:
            events.append({"raw": True, "time": time.time(), "kind": "dropped",
                           "bytes": "", "length": dropped, "gap_us": None,
                           "line": "serial"})
        return events

    def events(self, records: list[tuple[bool, int, bytes]]) -> list[dict]:
        """The trace events of captured records (sent, time ns, bytes), in order."""
        return [self._event(sent, start, end, data)
                for sent, start, end, data in self._bursts(records)]

    def _bursts(self, records):
        """(sent, first byte ns, last byte ns, bytes) of each burst.  A write's time is when
        it was handed to the port: its last byte leaves a character time per byte later; a
        read's is when its last byte had come."""
        burst: list | None = None
        previous_end = self._last_end_ns or 0
        for sent, t, data in records:
            span = len(data) * self._char_ns
            # what was read began a character time per byte before it was read, but not
            # before what went before had ended (a pty has no baud rate)
            if sent:
                start, end = t, t + span
            else:
                start = max(t - span, previous_end)
                end = max(t, start)
            previous_end = max(previous_end, end)
            if burst is not None and burst[0] == sent and start - burst[2] < self._quiet_ns:
                burst[2] = max(burst[2], end)
                burst[3] += data
                continue
            if burst is not None:
                yield tuple(burst)
            burst = [sent, start, end, bytearray(data)]
        if burst is not None:
            yield tuple(burst)

    def _event(self, sent: bool, start: int, end: int, burst: bytearray) -> dict:
        gap = None if self._last_end_ns is None else max(0, (start - self._last_end_ns) // 1000)
        self._last_end_ns = end
        data = bytes(burst)
        if self._answers:
            kind = "reply" if sent else "request" if self._valid(data) else "noise"
        elif sent:
            kind = "request"
            self._request = data
            self._deadline_ns = end + self._stout_ns
        elif self._request is not None and start <= self._deadline_ns:
            if self._replies(self._request, data):
                kind = "reply"
                self._request = None
            else:
                kind = "noise"
        else:
            kind = "unsolicited"
        wall = time.time() - (time.monotonic_ns() - start) / 1e9
        return {"raw": True, "time": wall, "kind": kind, "bytes": data.hex(" "),
                "length": len(data), "gap_us": gap, "line": "serial"}

    def _replies(self, request: bytes, reply: bytes) -> bool:
        """A whole, valid frame from the request's address, of its function or its
        exception."""
        if self._ascii:
            return self._valid(reply) and reply[1:3].upper() == request[1:3].upper()
        return len(reply) >= 4 and reply[0] == request[0] and \
            reply[1] & 0x7F == request[1] & 0x7F and self._valid(reply)

    def _valid(self, frame: bytes) -> bool:
        """A whole frame, its CRC right (ASCII: ':' to CR LF)."""
        if self._ascii:
            return frame[:1] == b":" and frame.endswith(b"\r\n")
        return len(frame) >= 4 and \
            crc16(frame[:-2]) == int.from_bytes(frame[-2:], "little")
