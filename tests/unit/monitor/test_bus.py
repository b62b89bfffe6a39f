"""BusDecoder: a listening line's bytes cut into frames by the C core's length rules, each
reply paired with the request it answers."""
import random

import pytest

from mbgw.line import native
from mbgw.monitor.bus import BusDecoder, MonitorCounters


def rtu(adu: bytes) -> bytes:
    return adu + native.crc16(adu).to_bytes(2, "little")


READ = bytes.fromhex("1103006b0003")                       # the published example
ANSWER = bytes.fromhex("110306ae4156524340")
OTHER = bytes.fromhex("0104000a0002")
OTHER_ANSWER = bytes.fromhex("010404000100ff")


class Heard:
    def __init__(self) -> None:
        self.counters = MonitorCounters()
        self.pairs: list[tuple[bytes, bytes]] = []
        self.events: list[tuple[str, bytes]] = []
        self.decoder = BusDecoder(self.counters, lambda q, r: self.pairs.append((q, r)),
                                  lambda adu, what: self.events.append((what, adu)))


def test_a_request_and_its_reply_are_a_pair() -> None:
    h = Heard()
    h.decoder.feed(rtu(READ) + rtu(ANSWER))
    assert h.pairs == [(READ, ANSWER)]
    c = h.counters
    assert (c.monitor_frames, c.monitor_answered, c.monitor_unanswered) == (2, 1, 0)


@pytest.mark.parametrize("seed", range(20))
def test_any_split_of_the_bytes_gives_the_same_pairs(seed: int) -> None:
    wire = rtu(READ) + rtu(ANSWER) + rtu(OTHER) + rtu(OTHER_ANSWER)
    rng = random.Random(seed)
    h = Heard()
    at = 0
    while at < len(wire):
        step = rng.randint(1, 6)
        h.decoder.feed(wire[at:at + step])
        at += step
    assert h.pairs == [(READ, ANSWER), (OTHER, OTHER_ANSWER)]
    assert not h.decoder.pending


def test_a_request_followed_by_another_is_unanswered() -> None:
    h = Heard()
    h.decoder.feed(rtu(READ) + rtu(OTHER) + rtu(OTHER_ANSWER))
    assert h.pairs == [(OTHER, OTHER_ANSWER)]
    assert h.counters.monitor_unanswered == 1
    assert ("unanswered", READ) in h.events


def test_a_retry_of_the_same_request_is_a_request_not_a_reply() -> None:
    h = Heard()
    h.decoder.feed(rtu(READ) + rtu(READ) + rtu(ANSWER))
    assert h.pairs == [(READ, ANSWER)]
    assert h.counters.monitor_unanswered == 1


def test_a_bad_crc_is_counted_and_never_paired() -> None:
    h = Heard()
    bad = bytearray(rtu(ANSWER))
    bad[4] ^= 0xFF
    h.decoder.feed(rtu(READ) + bytes(bad))
    assert h.pairs == []
    assert h.counters.monitor_crc_errors == 1


def test_an_exception_reply_answers() -> None:
    h = Heard()
    h.decoder.feed(rtu(READ) + rtu(bytes([0x11, 0x83, 0x02])))
    assert h.pairs == [(READ, bytes([0x11, 0x83, 0x02]))]


def test_a_broadcast_is_never_unanswered() -> None:
    h = Heard()
    h.decoder.feed(rtu(bytes.fromhex("000600010003")) + rtu(OTHER))
    assert h.counters.monitor_unanswered == 0


def test_a_frame_of_unknown_length_ends_when_the_line_is_quiet() -> None:
    h = Heard()
    h.decoder.feed(rtu(bytes([0x05, 0x41, 0x01, 0x02])))
    assert h.decoder.pending
    h.decoder.quiet()
    assert (h.counters.monitor_frames, h.decoder.pending) == (1, False)
