"""AsciiBusDecoder: a listening ASCII line's bytes cut into frames (':' to CR LF, LRC
checked), each reply paired with the request it answers.  Frames from the published
example (`:1103006B00037E`) and the C core's encoder."""

import pytest

from mbgw.line import native
from mbgw.monitor.bus import AsciiBusDecoder, MonitorCounters, decoder_for

READ = bytes.fromhex("1103006b0003")
ANSWER = bytes.fromhex("110306ae4156524340")


def test_the_published_frame_is_what_the_encoder_writes() -> None:
    assert native.ascii_encode(READ) == b":1103006B00037E\r\n"


@pytest.mark.parametrize("seed", range(10))
def test_a_request_and_its_reply_are_a_pair_at_any_split(ascii_heard, seed: int) -> None:
    wire = b"\x00noise" + native.ascii_encode(READ) + b"\r\n" + native.ascii_encode(ANSWER)
    ascii_heard.feed_in_pieces(wire, seed)
    assert isinstance(ascii_heard.decoder, AsciiBusDecoder)
    assert ascii_heard.pairs == [(READ, ANSWER)]
    c = ascii_heard.counters
    assert (c.monitor_frames, c.monitor_answered, c.monitor_crc_errors) == (2, 1, 0)
    assert c.noise_bytes == len(b"\x00noise\r\n")


def test_a_wrong_lrc_is_a_crc_error_and_the_request_goes_unanswered(ascii_heard) -> None:
    bad = bytearray(native.ascii_encode(ANSWER))
    bad[-3:-2] = b"0" if bad[-3:-2] != b"0" else b"1"      # the LRC's last hex digit
    ascii_heard.decoder.feed(native.ascii_encode(READ) + bytes(bad) + native.ascii_encode(READ))
    c = ascii_heard.counters
    assert ascii_heard.pairs == []
    assert (c.monitor_crc_errors, c.monitor_frames, c.monitor_unanswered) == (1, 2, 1)


def test_a_frame_cut_short_by_a_new_colon_or_the_quiet_is_a_crc_error(ascii_heard) -> None:
    ascii_heard.decoder.feed(b":1103" + native.ascii_encode(READ))
    assert ascii_heard.counters.monitor_crc_errors == 1 and ascii_heard.counters.monitor_frames == 1
    ascii_heard.decoder.feed(b":110306")
    assert ascii_heard.decoder.pending
    ascii_heard.decoder.quiet()
    assert ascii_heard.counters.monitor_crc_errors == 2 and not ascii_heard.decoder.pending


def test_an_rtu_line_keeps_the_rtu_decoder() -> None:
    assert not isinstance(decoder_for("rtu", MonitorCounters(), lambda q, r: None),
                          AsciiBusDecoder)
