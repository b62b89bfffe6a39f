"""RTU over TCP (mbgw.slave.rtu_client.RtuClient, mbgw.line.native.rtu_request_end): frames
cut from a stream by their length and CRC, never by a pause."""
import socket

import pytest

from mbgw.line import native
from mbgw.ops.counters import FaceCounters
from mbgw.slave.rtu_client import RtuClient

READ = native.rtu_adu(17, bytes.fromhex("03 0000 0002"))
WRITE = native.rtu_adu(17, bytes.fromhex("10 0001 0002 04 000a 000b"))
VENDOR = native.rtu_adu(17, bytes.fromhex("65 01 02"))       # a length no rule gives


def bad(frame: bytes) -> bytes:
    return frame[:-1] + bytes((frame[-1] ^ 0xFF,))


@pytest.mark.parametrize("data, end", [
    (READ, len(READ)), (READ[:5], 0), (READ + WRITE, len(READ)), (WRITE[:8], 0),
    (WRITE, len(WRITE)), (bad(READ), -len(READ)), (VENDOR + b"\x00", len(VENDOR)),
    (VENDOR[:-1], 0), (b"\x11", 0)])
def test_a_request_ends_by_its_length_and_crc(data, end):
    assert native.rtu_request_end(data) == end


def test_a_length_no_rule_gives_and_no_crc_in_a_whole_frame_is_dropped():
    junk = bytes((17, 0x65)) + bytes(native.RTU_MAX_ADU)
    assert native.rtu_request_end(junk) == -len(junk)


@pytest.fixture
def rtu():
    ours, theirs = socket.socketpair()
    client = RtuClient(ours, "127.0.0.1", "127.0.0.1:40000", "127.0.0.1:4001")
    client.face = FaceCounters()
    client.peer_end = theirs
    yield client
    ours.close()
    theirs.close()


def test_pieces_make_one_request_and_the_next_waits_for_the_reply(rtu):
    got = [rtu.received(bytes((b,)), 1) for b in READ]
    assert got[:-1] == [[]] * (len(READ) - 1)
    assert got[-1] == [(1, 17, READ[1:-2])]
    rtu.admitted()
    assert rtu.received(WRITE + READ, 2) == [] and rtu.held      # one in the gateway at once
    rtu.answered()
    assert rtu.received(b"", 3) == [(2, 17, WRITE[1:-2])]
    assert rtu.held                                             # READ still waits


def test_a_bad_crc_is_dropped_and_counted_and_the_next_request_framed(rtu):
    assert rtu.received(bad(READ) + WRITE, 1) == [(1, 17, WRITE[1:-2])]
    assert rtu.face.bad_frames == 1 and not rtu.closed


def test_the_reply_goes_back_as_rtu(rtu):
    rtu.send(native.frame(1, 17, bytes.fromhex("03 04 0064 0065")))
    assert rtu.peer_end.recv(64) == native.rtu_adu(17, bytes.fromhex("03 04 0064 0065"))
