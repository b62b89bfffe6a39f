"""tcp_reply_verdict (csrc/match.c): master mode's judgement of a server's Modbus TCP reply to
a request sent to a unit: its PDU's own length against its MBAP length, its unit id, then
reply_matches.  Published pairs (tests/vectors/pdu_pairs.txt), changed by hand."""
import pytest

from mbgw.line import native
from tests.unit.vectors import PDU_PAIRS

UNIT = 6
# the published pairs whose response's length its function code (and byte count) tell
KNOWN_LENGTH = ["FC01", "FC02", "FC03", "FC04", "FC05", "FC06", "FC07", "FC08", "FC0B", "FC0C",
                "FC0F", "FC10", "FC14", "FC15", "FC16", "FC17", "FC18", "FC2B/0E", "EXC"]


def _pair(label: str):
    return next(p for p in PDU_PAIRS if p.label == label)


def verdict(request: bytes, reply: bytes, reply_unit: int = UNIT) -> int:
    return native.tcp_reply_verdict(request, UNIT, reply_unit, reply)


@pytest.mark.parametrize("pair", PDU_PAIRS, ids=[p.label for p in PDU_PAIRS])
def test_a_published_response_from_the_unit_asked_answers(pair):
    assert verdict(pair.request, pair.response) == native.REPLY_ANSWERS, pair.source


@pytest.mark.parametrize("pair", PDU_PAIRS, ids=[p.label for p in PDU_PAIRS])
def test_a_published_response_from_another_unit_does_not(pair):
    for unit in (0, UNIT + 1, 0xFF):
        assert verdict(pair.request, pair.response, unit) == native.REPLY_WRONG_UNIT


@pytest.mark.parametrize("label", KNOWN_LENGTH)
def test_a_pdu_longer_or_shorter_than_it_says_is_a_bad_length(label):
    pair = _pair(label)
    assert verdict(pair.request, pair.response + b"\x00\x00") == native.REPLY_BAD_LENGTH
    assert verdict(pair.request, pair.response[:-1]) == native.REPLY_BAD_LENGTH
    # the frame cannot be read: its unit id is not looked at
    assert verdict(pair.request, pair.response[:-1], UNIT + 1) == native.REPLY_BAD_LENGTH


def test_a_lone_function_code_is_a_bad_length():
    assert verdict(_pair("FC03").request, b"\x03") == native.REPLY_BAD_LENGTH


def test_another_function_or_size_is_a_wrong_function():
    request, response = _pair("FC03").request, _pair("FC03").response
    assert verdict(request, b"\x04" + response[1:]) == native.REPLY_WRONG_FUNCTION
    assert verdict(request, b"\x84\x02") == native.REPLY_WRONG_FUNCTION
    one_less = bytes((0x03, response[1] - 2)) + response[2:-2]     # a register short
    assert verdict(request, one_less) == native.REPLY_WRONG_FUNCTION
    assert verdict(request, b"\x83\x02") == native.REPLY_ANSWERS


def test_a_write_reply_that_does_not_echo_is_a_wrong_function():
    pair = _pair("FC06")
    wrong = pair.response[:-1] + bytes((pair.response[-1] ^ 1,))
    assert verdict(pair.request, wrong) == native.REPLY_WRONG_FUNCTION
