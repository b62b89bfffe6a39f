"""Modbus TCP framing (mbgw.line.native), per the Messaging on TCP/IP Implementation Guide V1.0b,
3.1.3: transaction id (2), protocol id (2, 0 = Modbus), length (2, unit id + PDU), unit id
(1), big-endian, then the PDU."""
import errno

import pytest

from mbgw.errors import BadHeader
from mbgw.line import native

# The spec's FC03 example (Application Protocol 6.3) to unit 0x11, transaction 1.
READ_PDU = bytes.fromhex("03 00 6B 00 03")
READ_FRAME = bytes.fromhex("00 01 00 00 00 06 11") + READ_PDU
# Its response, to the same transaction.
REPLY_PDU = bytes.fromhex("03 06 02 2B 00 00 00 64")
REPLY_FRAME = bytes.fromhex("00 01 00 00 00 09 11") + REPLY_PDU


def _split(buf: bytearray) -> list:
    return list(native.split_frames(buf))


def test_frame_builds_the_header_from_the_pdu_length():
    assert native.frame(1, 0x11, READ_PDU) == READ_FRAME
    assert native.frame(1, 0x11, REPLY_PDU) == REPLY_FRAME


def test_frame_keeps_transaction_id_and_unit():
    assert native.frame(0xBEEF, 0xFF, b"\x83\x0B") == bytes.fromhex("BE EF 00 00 00 03 FF 83 0B")


def test_one_whole_frame():
    buf = bytearray(READ_FRAME)
    assert _split(buf) == [(1, 0x11, READ_PDU)]
    assert buf == b""


def test_frames_built_by_frame_split_back():
    pdus = [b"\x07", READ_PDU, bytes(253)]
    buf = bytearray(b"".join(native.frame(tid, 5, pdu) for tid, pdu in enumerate(pdus)))
    assert _split(buf) == [(tid, 5, pdu) for tid, pdu in enumerate(pdus)]


def test_several_frames_in_one_buffer_keep_their_order():
    second = native.frame(2, 0x12, b"\x11")
    buf = bytearray(READ_FRAME + second + REPLY_FRAME)
    assert _split(buf) == [(1, 0x11, READ_PDU), (2, 0x12, b"\x11"), (1, 0x11, REPLY_PDU)]
    assert buf == b""


@pytest.mark.parametrize("cut", range(len(READ_FRAME)))
def test_partial_frame_yields_nothing_and_stays_in_the_buffer(cut):
    buf = bytearray(READ_FRAME[:cut])
    assert _split(buf) == []
    assert buf == READ_FRAME[:cut]


def test_frame_followed_by_part_of_the_next_leaves_that_part():
    buf = bytearray(READ_FRAME + REPLY_FRAME[:9])
    assert _split(buf) == [(1, 0x11, READ_PDU)]
    assert buf == REPLY_FRAME[:9]


def test_byte_by_byte_feeding_yields_each_frame_on_its_last_byte():
    stream = READ_FRAME + REPLY_FRAME
    buf = bytearray()
    seen = []
    for i, byte in enumerate(stream):
        buf.append(byte)
        for frame in native.split_frames(buf):
            seen.append((i, frame))
    assert seen == [(len(READ_FRAME) - 1, (1, 0x11, READ_PDU)),
                    (len(stream) - 1, (1, 0x11, REPLY_PDU))]
    assert buf == b""


@pytest.mark.parametrize("protocol", [1, 0x1234, 0xFFFF])
def test_protocol_id_other_than_zero_is_a_bad_header(protocol):
    header = bytes.fromhex("00 01") + protocol.to_bytes(2, "big") + bytes.fromhex("00 06 11")
    with pytest.raises(BadHeader):
        _split(bytearray(header + READ_PDU))


@pytest.mark.parametrize("length", [0, 1, 255, 256, 0xFFFF])
def test_length_outside_2_to_254_is_a_bad_header(length):
    header = bytes.fromhex("00 01 00 00") + length.to_bytes(2, "big") + b"\x11"
    with pytest.raises(BadHeader):
        _split(bytearray(header))


@pytest.mark.parametrize("length", [2, 254])
def test_length_limits_2_and_254_are_accepted(length):
    pdu = bytes(length - 1)
    buf = bytearray(bytes.fromhex("00 01 00 00") + length.to_bytes(2, "big") + b"\x11" + pdu)
    assert _split(buf) == [(1, 0x11, pdu)]


def test_the_c_rule_gives_the_frame_length_or_why_none():
    assert [native.frame_length(0, length) for length in (2, 6, 254)] == [8, 12, 260]
    assert native.frame_length(1, 6) == -errno.EPROTO
    assert native.frame_length(0, 1) == native.frame_length(0, 255) == -errno.EMSGSIZE
    assert str(native.bad_header(-errno.EPROTO, 7, 6)) == "protocol id 7"
    assert str(native.bad_header(-errno.EMSGSIZE, 0, 255)) == "length 255"


def test_bad_header_is_raised_as_soon_as_the_header_is_complete():
    header = bytes.fromhex("00 01 00 07 00 06 11")       # protocol 7
    buf = bytearray(header[:6])
    assert _split(buf) == []
    buf.append(header[6])
    with pytest.raises(BadHeader):
        _split(buf)


def test_frames_before_a_bad_header_are_still_delivered():
    bad = bytes.fromhex("00 02 00 01 00 06 11") + READ_PDU
    buf = bytearray(READ_FRAME + bad)
    seen = []
    with pytest.raises(BadHeader):
        for frame in native.split_frames(buf):
            seen.append(frame)
    assert seen == [(1, 0x11, READ_PDU)]


def test_bad_header_is_a_value_error():
    assert issubclass(BadHeader, ValueError)
