"""Transparent mode's frame rules without I/O (mbgw/transparent/frames.py): how Receiver cuts
the line's bytes into frames for each kind of end, fed a byte at a time as a slow line
delivers them; the CRC checked and added by Rules, against the published CRC-16/MODBUS
vectors of tests/vectors/crc16.txt (none of them produced by mbgw)."""
import pytest

from mbgw.config.model import SerialConfig
from mbgw.config.transparent import EOF_CHARS, TransparentConfig
from mbgw.transparent.frames import MAX_FRAME, Receiver, Rules
from tests.unit.vectors import CHECK_VECTORS


def rules(baudrate: int = 9600, **options) -> Rules:
    return Rules(TransparentConfig(**options), SerialConfig(device="/dev/null",
                                                            baudrate=baudrate))


def fed_byte_by_byte(receiver: Receiver, wire: bytes) -> list[tuple[int, bytes]]:
    """(the index of the byte that completed it, the frame) for every frame wire holds."""
    done = []
    for at in range(len(wire)):
        frames, overflow = receiver.feed(wire[at:at + 1])
        assert not overflow
        done += [(at, frame) for frame in frames]
    return done


# --- the end of a frame, for each kind ---

@pytest.mark.parametrize("eof, end", sorted(EOF_CHARS.items()))
def test_a_frame_ends_with_its_end_characters_and_not_a_byte_before(eof, end):
    wire = b"AB" + end
    assert fed_byte_by_byte(Receiver(rules(eof=eof)), wire) == [(len(wire) - 1, wire)]


def test_eof_char_ends_a_frame_at_the_character_given():
    receiver = Receiver(rules(eof="char", eof_char=0x7E))
    assert fed_byte_by_byte(receiver, b"\x01\r\n\x02\x7e") == [(4, b"\x01\r\n\x02\x7e")]


@pytest.mark.parametrize("eof, wire", [("crlf", b"A\n\r"), ("lfcr", b"A\r\n")])
def test_two_end_characters_in_the_other_order_end_nothing(eof, wire):
    receiver = Receiver(rules(eof=eof))
    assert fed_byte_by_byte(receiver, wire) == []
    assert receiver.pending == wire


def test_eof_length_the_first_byte_counts_the_bytes_after_it():
    wire = bytes([3]) + b"\r\nA"                       # end characters are data here
    assert fed_byte_by_byte(Receiver(rules(eof="length")), wire) == [(3, wire)]


def test_eof_length_zero_is_a_frame_of_its_length_byte_alone():
    assert fed_byte_by_byte(Receiver(rules(eof="length")), b"\x00\x00") == [
        (0, b"\x00"), (1, b"\x00")]


def test_eof_timeout_no_byte_ends_a_frame_only_the_quiet_line_does():
    receiver = Receiver(rules(eof="timeout"))
    assert fed_byte_by_byte(receiver, b"\x03AB\r\n") == []
    assert receiver.quiet() == b"\x03AB\r\n"
    assert receiver.pending == b"" and receiver.quiet() == b""


@pytest.mark.parametrize("eof", ["cr", "length"])
def test_a_quiet_line_drops_what_came_of_a_frame_that_ends_otherwise(eof):
    receiver = Receiver(rules(eof=eof))
    assert receiver.feed(b"\x05AB") == ([], False)
    assert receiver.quiet() is None
    assert receiver.feed(b"\x01C" if eof == "length" else b"C\r") == (
        [b"\x01C" if eof == "length" else b"C\r"], False)


def test_one_read_may_hold_several_frames_and_the_start_of_the_next():
    receiver = Receiver(rules(eof="crlf"))
    assert receiver.feed(b"one\r\ntwo\r\nthr") == ([b"one\r\n", b"two\r\n"], False)
    assert receiver.feed(b"ee\r\n") == ([b"three\r\n"], False)


def test_a_frame_with_no_end_is_dropped_once_it_outgrows_max_frame():
    receiver = Receiver(rules(eof="cr"))
    assert receiver.feed(b"x" * MAX_FRAME) == ([], False)
    assert receiver.feed(b"x") == ([], True)
    assert receiver.pending == b""
    assert receiver.feed(b"next\r") == ([b"next\r"], False)


def test_eof_timeout_0_is_the_lines_t35_rounded_up_to_a_millisecond():
    # Modbus over serial line V1.02, 2.5.1.1: t3.5 is 3.5 characters, 1.75 ms above 19200
    # bit/s; a character is 10 bits in 8N1 (3.5 * 10 / 9600 s = 3.65 ms)
    assert rules(eof="timeout").eof_timeout_ms == 4
    assert rules(38400, eof="timeout").eof_timeout_ms == 2
    assert rules(eof="timeout", eof_timeout_ms=250).eof_timeout_ms == 250


# --- the CRC (--crc): published CRC-16/MODBUS vectors ---

def test_the_vectors_are_there():
    assert len(CHECK_VECTORS) >= 10


@pytest.mark.parametrize("v", CHECK_VECTORS, ids=lambda v: v.where)
def test_a_received_frame_with_its_published_crc_is_kept_without_it(v):
    r = rules(eof="timeout", crc=True)
    receiver = Receiver(r)
    assert fed_byte_by_byte(receiver, v.frame + v.crc_wire) == []
    wire = receiver.quiet()
    assert wire == v.frame + v.crc_wire
    assert r.payload(wire) == v.frame


@pytest.mark.parametrize("v", CHECK_VECTORS, ids=lambda v: v.where)
def test_a_received_frame_with_a_wrong_crc_is_refused(v):
    r = rules(eof="timeout", crc=True)
    assert r.payload(v.frame + bytes([v.crc_wire[0] ^ 0x01, v.crc_wire[1]])) is None
    assert r.payload(v.frame + v.crc_wire[::-1]) is None or v.crc_wire[0] == v.crc_wire[1]


@pytest.mark.parametrize("v", CHECK_VECTORS, ids=lambda v: v.where)
def test_a_sent_frame_gets_its_published_crc_low_byte_first(v):
    r = rules(eof="timeout", crc=True)
    area = bytes([len(v.frame)]) + v.frame + b"\0" * 7
    assert r.tx_frame(area, None) == (v.frame + v.crc_wire, None)


def test_with_crc_an_end_character_frame_is_complete_two_bytes_after_the_end():
    v = next(v for v in CHECK_VECTORS if v.frame[-1] not in v.frame[:-1])
    receiver = Receiver(rules(eof="char", eof_char=v.frame[-1], crc=True))
    wire = v.frame + v.crc_wire
    assert fed_byte_by_byte(receiver, wire) == [(len(wire) - 1, wire)]


def test_with_crc_a_length_frame_is_complete_two_bytes_after_its_data():
    v = CHECK_VECTORS[0]
    r = rules(eof="length", crc=True)
    frame = bytes([len(v.frame)]) + v.frame          # the CRC covers the length byte too
    wire = r.tx_frame(frame + b"\0\0", None)[0]
    assert wire is not None and wire[:-2] == frame
    assert fed_byte_by_byte(Receiver(r), wire) == [(len(wire) - 1, wire)]
    assert r.payload(wire) == frame


def test_a_frame_too_short_to_hold_a_crc_is_refused():
    r = rules(eof="timeout", crc=True)
    assert r.payload(b"") is None and r.payload(b"\x00\x00") is None


# --- the table's areas ---

def test_the_rx_area_holds_the_frame_two_bytes_to_a_register_high_first():
    r = rules(eof="cr", rx_size=6)
    assert r.rx_area(b"ABC\r", 0) == ([0x4142, 0x430D, 0x0000], False)


def test_the_rx_area_cuts_a_frame_too_big_and_says_so():
    r = rules(eof="cr", rx_size=3)
    assert r.rx_area(b"ABCD\r", 0) == ([0x4142, 0x4300], True)


def test_with_trigger_the_rx_area_starts_with_the_counter():
    r = rules(eof="cr", rx_size=4, trigger=True)
    assert r.rx_area(b"AB\r", 7) == ([0x0741, 0x420D], False)
    assert r.rx_area(b"ABC\r", 8) == ([0x0841, 0x4243], True)


def test_eof_timeout_rx_area_says_how_many_bytes_of_the_frame_it_holds():
    r = rules(eof="timeout", rx_size=4)
    assert r.rx_area(b"ABCDE", 0) == ([0x0341, 0x4243], True)


def test_the_tx_area_sends_up_to_the_end_and_refuses_an_area_with_none():
    r = rules(eof="crlf")
    assert r.tx_frame(b"hi\r\nrest", None) == (b"hi\r\n", None)
    assert r.tx_frame(b"no end", None) == (b"", None)


def test_the_tx_area_of_a_length_frame_sends_the_length_byte_and_refuses_a_short_area():
    r = rules(eof="length")
    assert r.tx_frame(b"\x02AB...", None) == (b"\x02AB", None)
    assert r.tx_frame(b"\x05AB", None) == (b"", None)


def test_with_trigger_the_tx_area_sends_only_when_its_counter_changes():
    r = rules(eof="cr", trigger=True)
    assert r.tx_frame(b"\x01go\r", 1) == (None, 1)
    assert r.tx_frame(b"\x02go\r", 1) == (b"go\r", 2)
