"""A remote line's framing (mbgw.slave.remote_framing) over what a stream or datagrams bring:
a reply cut from its length and check wherever the stream was cut, noise before it skipped,
and only the reply to the outstanding request taken (our transaction id, the unit, the
function and length); the rest counted stray.  The frames are the specs' (tests/modbus.py),
fed as a socket would give them."""
import struct
import time
from collections import deque

import pytest

from mbgw.errors import LineTimeout
from mbgw.ops.counters import RemoteCounters
from mbgw.slave.remote_framing import remote_framing
from tests.modbus import read_holding, rtu_frame

UNIT = 7
REQUEST = bytes((UNIT,)) + read_holding(0, 2)
REPLY = bytes((UNIT, 0x03, 4, 0, 100, 0, 101))


class Line:
    """What the framing uses of a RemoteLine: the socket's reads scripted, writes kept."""

    def __init__(self, kind: str, *reads: bytes) -> None:
        self.kind = kind
        self.stream = not kind.endswith("-udp")
        self.counters = RemoteCounters()
        self.reads = deque(reads)
        self.sent: list[bytes] = []
        self.dropped = False
        self.back = 0

    def send(self, wire: bytes) -> int:
        self.sent.append(wire)
        return time.monotonic_ns()

    def discard(self) -> int:
        return 0

    def receive(self, deadline_ns: int):
        return memoryview(self.reads.popleft()) if self.reads else None

    def answered(self) -> None:
        self.back += 1

    def drop(self, why: str) -> None:
        self.dropped = True


def exchange(line: Line, request: bytes = REQUEST):
    framing = remote_framing(line)      # type: ignore[arg-type]
    framing.send(request)
    return framing.receive(request, time.monotonic_ns() + 10**9)


def one_byte_at_a_time(frame: bytes) -> list[bytes]:
    return [frame[i:i + 1] for i in range(len(frame))]


def test_an_rtu_reply_in_one_byte_segments_is_one_frame():
    line = Line("rtu-over-tcp", *one_byte_at_a_time(rtu_frame(REPLY)))
    got = exchange(line)
    assert got.frame == REPLY
    assert line.sent == [rtu_frame(REQUEST)]
    assert line.back == 1


def test_two_rtu_frames_in_one_segment_a_stray_then_the_reply():
    stray = rtu_frame(bytes((UNIT, 0x03, 2, 0, 9)))          # another request's size
    line = Line("rtu-over-tcp", stray + rtu_frame(REPLY)[:5], rtu_frame(REPLY)[5:])
    assert exchange(line).frame == REPLY
    assert line.counters.stray_replies == 1


def test_noise_and_a_bad_crc_before_the_reply_are_skipped():
    broken = bytearray(rtu_frame(REPLY))
    broken[-1] ^= 0xFF
    line = Line("rtu-over-tcp", b"\x00\xff" + bytes(broken) + rtu_frame(REPLY))
    assert exchange(line).frame == REPLY
    assert line.counters.noise_bytes >= 2 + 1
    assert line.counters.stray_replies == 0


def test_a_device_identification_reply_is_cut_by_its_objects():
    request = bytes((UNIT, 0x2B, 0x0E, 0x01, 0x00))
    reply = bytes((UNIT, 0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0x01, 0x00, 0x03)) + b"abc"
    line = Line("rtu-over-tcp", rtu_frame(reply) + rtu_frame(REPLY))
    assert exchange(line, request).frame == reply


def test_a_reply_of_no_known_length_is_the_shortest_prefix_with_a_good_crc():
    request = bytes((UNIT, 0x41, 0x01))          # a vendor's function code
    reply = bytes((UNIT, 0x41, 0x01, 0x02, 0x03))
    line = Line("rtu-over-tcp", *one_byte_at_a_time(rtu_frame(reply) + b"\x99"))
    assert exchange(line, request).frame == reply


def test_no_reply_by_the_deadline_is_a_timeout():
    got = exchange(Line("rtu-over-tcp", rtu_frame(REPLY)[:4]))
    assert isinstance(got.fault, LineTimeout)
    assert got.frame is None


def mbap_reply(tid: int, unit: int = UNIT, protocol: int = 0, pdu: bytes = REPLY[1:]) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1, unit) + pdu


def test_modbus_tcp_takes_only_its_own_transaction_id_and_unit():
    line = Line("modbus-tcp", mbap_reply(0x0000) + mbap_reply(1, unit=UNIT + 1)[:3],
                mbap_reply(1, unit=UNIT + 1)[3:] + mbap_reply(1)[:8], mbap_reply(1)[8:])
    got = exchange(line)
    assert line.sent == [struct.pack(">HHHB", 1, 0, 6, UNIT) + REQUEST[1:]]
    assert got.frame == REPLY
    assert line.counters.stray_replies == 2


def test_modbus_tcp_refuses_a_reply_of_another_size():
    line = Line("modbus-tcp", mbap_reply(1, pdu=bytes((3, 2, 0, 1))))
    assert isinstance(exchange(line).fault, LineTimeout)
    assert line.counters.stray_replies == 1


def test_a_header_of_another_protocol_ends_the_connection():
    line = Line("modbus-tcp", mbap_reply(1, protocol=1) + mbap_reply(1))
    assert isinstance(exchange(line).fault, LineTimeout)
    assert line.dropped


@pytest.mark.parametrize("kind", ["modbus-udp", "rtu-over-udp"])
def test_a_datagram_is_one_frame_what_follows_it_is_noise(kind):
    reply = mbap_reply(1) if kind == "modbus-udp" else rtu_frame(REPLY)
    stray = mbap_reply(9) if kind == "modbus-udp" else b"\x01\x02\x03"
    line = Line(kind, stray, reply[:-1], reply)
    assert exchange(line).frame == REPLY


def test_an_ascii_reply_behind_noise():
    lrc = (-sum(REPLY)) & 0xFF
    frame = b":" + (REPLY + bytes((lrc,))).hex().upper().encode() + b"\r\n"
    line = Line("ascii-over-tcp", b"\x00garbage", frame[:9], frame[9:])
    assert exchange(line).frame == REPLY
