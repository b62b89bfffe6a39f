"""The framing of a remote line (mbgw.line.remote): how SerialMaster's requests and replies
travel to a device across the network, in the same shape as the serial line's framings
(mbgw.slave.framing: send, receive, resync, the port to wait on).

A TCP stream is cut anywhere: one reply may come in many segments, or two in one.  So a
reply's end is found from its length (the MBAP header's, or the RTU length rules of the C
core, csrc/rtu.c) and its check (CRC, LRC), never from a silence.  A reply whose length its
header does not give is the shortest prefix with a good CRC that answers the request.  Bytes
before a reply that begin no frame answering the request are noise, skipped.  Over UDP each
datagram is one frame.

Matching is ours on every kind: a reply is taken only if it answers the one outstanding
request (Modbus TCP: our own transaction id, protocol id 0, the unit; every kind: the
function and the length, csrc/match.c).  Anything else whole -- late, duplicate, unmatched --
is dropped and counted stray_replies.  Whatever waits unread when a request goes out is
dropped, and a new connection starts empty, so half a frame is never taken for a reply.
"""
import errno
import struct
import time

from mbgw.errors import ChecksumError, FrameError, LineTimeout
from mbgw.line import native
from mbgw.line.native import NO_FORWARD, Forward, Reception, reply_matches
from mbgw.line.remote import RemoteCounters, RemoteLine

MBAP = struct.Struct(">HHHB")       # transaction id, protocol id, length, unit id
TIMED_OUT = LineTimeout()
BAD_HEADER = -errno.EPROTO     # RemoteLine.exchange: the stream is out of step


class _RemoteFraming:
    """What every kind shares: the buffer of what came, the send, the wait for a reply."""
    inter_frame_us = 0      # no line silence to keep; `pause` is the line's interframe_ms

    def __init__(self, line: RemoteLine, counters: RemoteCounters) -> None:
        self.line = line
        self.port = line
        self._counters = counters
        self._rx = bytearray()
        self._noise = 0

    def exchanges(self, adu: bytes) -> bool:
        return False

    def resync(self, last_byte_ns: int) -> int:
        return time.monotonic_ns()

    def send(self, adu: bytes) -> int:
        """adu (address + PDU) out; what came after the last reply, read with it or not yet,
        is no reply to it."""
        self._counters.stray_replies += bool(self._rx) + bool(self.line.discard())
        self._rx.clear()
        return self.line.send(self._encode(adu))

    def receive(self, adu: bytes, deadline: int, forward: Forward = NO_FORWARD) -> Reception:
        """The reply to adu, address + PDU; a LineTimeout fault when none came by deadline
        or the connection ended first.  adu of function 0 (SerialMaster's listening, the
        line idle): nothing is outstanding, so what came is stray."""
        if len(adu) < 2 or adu[1] == 0:
            return self._stray_input()
        line = self.line
        rx = self._rx
        self._noise = 0
        while True:
            frame = self._cut(adu) if rx else None
            if frame is not None:
                line.answered()
                return Reception(frame, None, -1, len(frame), self._skipped(), -1, 0,
                                 time.monotonic_ns())
            if not line.stream and rx:         # a datagram is one frame: the rest is noise
                self._noise += len(rx)
                rx.clear()
            got = line.receive(deadline)
            if not got:                        # too late, or the connection ended
                rx.clear()
                return Reception(None, TIMED_OUT, -1, 0, self._skipped(), -1, 0,
                                 time.monotonic_ns())
            rx += got

    def receive_unchecked(self, adu: bytes, deadline: int) -> Reception:
        return self.receive(adu, deadline)

    def _stray_input(self) -> Reception:
        if self.line.discard():
            self._counters.stray_replies += 1
        self._rx.clear()
        return Reception(None, TIMED_OUT, -1, 0, 0, -1, 0, time.monotonic_ns())

    def _skipped(self) -> int:
        noise, self._noise = self._noise, 0
        self._counters.noise_bytes += noise
        return noise

    def _stray(self, length: int) -> None:
        """A whole frame that answers nothing outstanding: dropped."""
        del self._rx[:length]
        self._counters.stray_replies += 1

    def _encode(self, adu: bytes) -> bytes:
        raise NotImplementedError

    def _cut(self, adu: bytes) -> bytes | None:
        """The reply to adu at the start of the buffer, taken out (address + PDU); None
        until one is whole.  Strays and noise before it are dropped."""
        raise NotImplementedError


class MbapFraming(_RemoteFraming):
    """modbus-tcp and modbus-udp: the MBAP header, with our own transaction ids."""

    def __init__(self, line: RemoteLine, counters: RemoteCounters) -> None:
        super().__init__(line, counters)
        self._tid = 0

    def exchanges(self, adu: bytes) -> bool:
        """exchange() serves Modbus TCP; Modbus/UDP's datagrams go by send() and receive()."""
        return self.line.stream

    def exchange(self, adu: bytes, stout_ns: int, forward: Forward = NO_FORWARD) -> Reception:
        """send() and receive() in one C call (RemoteLine.exchange), the deadline stout_ns
        after the send: the reply to adu, or a LineTimeout fault when none came in time or
        the connection ended first.  Raises TargetUnreachable as send() does."""
        return self.reception(self.line.exchange(adu, self.next_tid(), stout_ns, forward))

    def next_tid(self) -> int:
        """The transaction id of the request about to go (what a receive of a frame nobody
        asked for left unread is dropped with it)."""
        self._counters.stray_replies += bool(self._rx)
        self._rx.clear()
        self._tid = tid = (self._tid + 1) & 0xFFFF
        return tid

    def reception(self, n: int) -> Reception:
        """What the C exchange (or a lent client's take, mbgw.slave.loans) found: n, the
        reply's length or -errno; the rest in the line's mbap.result."""
        line = self.line
        got = line.mbap.result
        counters = self._counters
        counters.stray_replies += bool(got.stale) + got.strays + bool(got.left) + \
            (n == BAD_HEADER)
        counters.noise_bytes += got.noise
        if n < 0:
            return Reception(None, TIMED_OUT, -1, 0, got.noise, -1, got.sent_ns, got.end_ns)
        line.answered()
        frame = line.mbap.reply(n)
        return Reception(frame, None, -1, len(frame), 0, got.forwarded, got.sent_ns,
                         got.end_ns)

    def exchanged(self, adu: bytes, got: Reception) -> Reception:
        """A lent client's request the line's thread took (SerialMaster.book_taken): what
        its reply_to_loan found, as reception() made it."""
        return got

    def _encode(self, adu: bytes) -> bytes:
        self._tid = (self._tid + 1) & 0xFFFF
        return MBAP.pack(self._tid, 0, len(adu), adu[0]) + adu[1:]

    def _cut(self, adu: bytes) -> bytes | None:
        rx = self._rx
        while len(rx) >= MBAP.size:
            tid, protocol, length, unit = MBAP.unpack_from(rx)
            end = native.frame_length(protocol, length)
            if end < 0:           # the stream is out of step: nothing in it can be trusted
                self._counters.stray_replies += 1
                self._noise += len(rx)
                rx.clear()
                self.line.drop("bad MBAP header")
                return None
            if len(rx) < end:
                return None
            frame = bytes(rx[MBAP.size - 1:end])       # unit + PDU
            if tid == self._tid and unit == adu[0] and reply_matches(adu[1:], frame[1:]):
                del rx[:end]
                return frame
            self._stray(end)
        return None


class RtuStreamFraming(_RemoteFraming):
    """rtu-over-tcp and rtu-over-udp: RTU frames, CRC and all, as on the serial line."""

    def _encode(self, adu: bytes) -> bytes:
        crc = native.crc16(adu)
        return adu + bytes((crc & 0xFF, crc >> 8))

    def _cut(self, adu: bytes) -> bytes | None:
        rx = self._rx
        address, function = adu[0], adu[1]
        while len(rx) >= 2:
            if rx[0] != address or rx[1] & 0x7F != function:
                self._skip(1)
                continue
            have = bytes(rx)
            end = native.rtu_reply_length(len(adu), have)
            if end == native.LEN_UNKNOWN:
                end = shortest_reply(adu, have)
                if end == 0 and len(rx) > native.RTU_MAX_ADU:
                    self._skip(1)
                    continue
            if end == 0 or len(rx) < end:
                return None
            if native.crc16(have[:end]):
                self._skip(1)               # not a frame: noise, or a frame cut short
                continue
            frame = have[:end - native.CRC_LEN]
            if reply_matches(adu[1:], frame[1:]):
                del rx[:end]
                return frame
            self._stray(end)
        return None

    def _skip(self, n: int) -> None:
        del self._rx[:n]
        self._noise += n


def shortest_reply(adu: bytes, have: bytes) -> int:
    """The length of the shortest prefix of have with a good CRC that answers adu (a reply
    whose length its header does not give); 0 when none is whole yet."""
    for end in range(4, min(len(have), native.RTU_MAX_ADU) + 1):
        if not native.crc16(have[:end]) and \
                reply_matches(adu[1:], have[1:end - native.CRC_LEN]):
            return end
    return 0


class AsciiStreamFraming(_RemoteFraming):
    """ascii-over-tcp: ':' hex LRC CR LF frames, as on the serial line."""

    def _encode(self, adu: bytes) -> bytes:
        return native.ascii_encode(adu)

    def _cut(self, adu: bytes) -> bytes | None:
        rx = self._rx
        while rx:
            start = rx.find(b":")
            if start < 0:
                self._noise += len(rx)
                rx.clear()
                return None
            if start:
                del rx[:start]
                self._noise += start
            end = rx.find(b"\r\n")
            if end < 0:
                if len(rx) > native.ASCII_MAX_FRAME:
                    del rx[:1]
                    self._noise += 1
                    continue
                return None
            end += 2
            try:
                frame = native.ascii_decode(bytes(rx[:end]))
            except (ChecksumError, FrameError):
                del rx[:1]                  # the next ':' may begin the reply
                self._noise += 1
                continue
            if len(frame) >= 2 and frame[0] == adu[0] and reply_matches(adu[1:], frame[1:]):
                del rx[:end]
                return frame
            self._stray(end)
        return None


def remote_framing(line: RemoteLine) -> _RemoteFraming:
    """The framing of line's kind of `connect`."""
    if line.kind in ("modbus-tcp", "modbus-udp"):
        return MbapFraming(line, line.counters)
    if line.kind == "ascii-over-tcp":
        return AsciiStreamFraming(line, line.counters)
    return RtuStreamFraming(line, line.counters)
