"""BusDecoder: a listening line's bytes cut into frames by the C core's length rules, each
reply paired with the request it answers."""

import pytest

from mbgw.line import native


def rtu(adu: bytes) -> bytes:
    return adu + native.crc16(adu).to_bytes(2, "little")


READ = bytes.fromhex("1103006b0003")                       # the published example
ANSWER = bytes.fromhex("110306ae4156524340")
OTHER = bytes.fromhex("0104000a0002")
OTHER_ANSWER = bytes.fromhex("010404000100ff")


def test_a_request_and_its_reply_are_a_pair(heard) -> None:
    heard.decoder.feed(rtu(READ) + rtu(ANSWER))
    assert heard.pairs == [(READ, ANSWER)]
    c = heard.counters
    assert (c.monitor_frames, c.monitor_answered, c.monitor_unanswered) == (2, 1, 0)


@pytest.mark.parametrize("seed", range(20))
def test_any_split_of_the_bytes_gives_the_same_pairs(heard, seed: int) -> None:
    wire = rtu(READ) + rtu(ANSWER) + rtu(OTHER) + rtu(OTHER_ANSWER)
    heard.feed_in_pieces(wire, seed)
    assert heard.pairs == [(READ, ANSWER), (OTHER, OTHER_ANSWER)]
    assert not heard.decoder.pending


def test_a_request_followed_by_another_is_unanswered(heard) -> None:
    heard.decoder.feed(rtu(READ) + rtu(OTHER) + rtu(OTHER_ANSWER))
    assert heard.pairs == [(OTHER, OTHER_ANSWER)]
    assert heard.counters.monitor_unanswered == 1
    assert ("unanswered", READ) in heard.events


def test_a_retry_of_the_same_request_is_a_request_not_a_reply(heard) -> None:
    heard.decoder.feed(rtu(READ) + rtu(READ) + rtu(ANSWER))
    assert heard.pairs == [(READ, ANSWER)]
    assert heard.counters.monitor_unanswered == 1


def test_a_bad_crc_is_counted_and_never_paired(heard) -> None:
    bad = bytearray(rtu(ANSWER))
    bad[4] ^= 0xFF
    heard.decoder.feed(rtu(READ) + bytes(bad))
    assert heard.pairs == []
    assert heard.counters.monitor_crc_errors == 1


def test_an_exception_reply_answers(heard) -> None:
    heard.decoder.feed(rtu(READ) + rtu(bytes([0x11, 0x83, 0x02])))
    assert heard.pairs == [(READ, bytes([0x11, 0x83, 0x02]))]


def test_a_broadcast_is_never_unanswered(heard) -> None:
    heard.decoder.feed(rtu(bytes.fromhex("000600010003")) + rtu(OTHER))
    assert heard.counters.monitor_unanswered == 0


def test_a_frame_of_unknown_length_ends_when_the_line_is_quiet(heard) -> None:
    heard.decoder.feed(rtu(bytes([0x05, 0x41, 0x01, 0x02])))
    assert heard.decoder.pending
    heard.decoder.quiet()
    assert (heard.counters.monitor_frames, heard.decoder.pending) == (1, False)
