"""reply_matches (csrc/match.c): can this reply PDU be the answer to that request PDU?"""
import pytest

from mbgw.line.native import reply_matches
from mbgw.protocol import pdu
from tests.unit.vectors import PDU_PAIRS


def _pair(label: str):
    return next(p for p in PDU_PAIRS if p.label == label)


def _with(data: bytes, index: int, value: int) -> bytes:
    changed = bytearray(data)
    changed[index] = value
    return bytes(changed)


@pytest.mark.parametrize("pair", PDU_PAIRS, ids=[p.label for p in PDU_PAIRS])
def test_published_response_matches_its_request(pair):
    assert reply_matches(pair.request, pair.response), pair.source


@pytest.mark.parametrize("pair", PDU_PAIRS, ids=[p.label for p in PDU_PAIRS])
def test_exception_for_the_requests_function_matches(pair):
    function = pair.request[0]
    for code in (0x01, 0x02, 0x04, pdu.GATEWAY_PATH_UNAVAILABLE, pdu.GATEWAY_TARGET_FAILED):
        assert reply_matches(pair.request, bytes((function | 0x80, code)))


def test_exception_of_another_function_does_not_match():
    request = _pair("FC03").request
    assert not reply_matches(request, b"\x84\x02")
    assert not reply_matches(request, b"\x81\x02")


def test_exception_reply_of_the_wrong_size_does_not_match():
    request = _pair("FC03").request
    assert not reply_matches(request, b"\x83")
    assert not reply_matches(request, b"\x83\x02\x00")


@pytest.mark.parametrize("pair", PDU_PAIRS, ids=[p.label for p in PDU_PAIRS])
def test_reply_with_another_function_does_not_match(pair):
    other = 0x03 if pair.request[0] != 0x03 else 0x04
    assert not reply_matches(pair.request, bytes((other,)) + pair.response[1:])


@pytest.mark.parametrize("label", ["FC01", "FC02", "FC03", "FC04", "FC17",
                                   "VPG01", "VPG02", "VPG03", "VPG04"])
def test_read_reply_with_a_byte_count_the_request_did_not_ask_for(label):
    pair = _pair(label)
    count = pair.response[1]
    longer = pair.response[:1] + bytes((count + 2,)) + pair.response[2:] + b"\x00\x00"
    shorter = pair.response[:1] + bytes((count - 1,)) + pair.response[2:-1]
    assert not reply_matches(pair.request, longer)
    assert not reply_matches(pair.request, shorter)


@pytest.mark.parametrize("label", ["FC01", "FC02", "FC03", "FC04", "FC17", "VPG03"])
def test_read_reply_shorter_or_longer_than_its_byte_count(label):
    pair = _pair(label)
    assert not reply_matches(pair.request, pair.response[:-1])
    assert not reply_matches(pair.request, pair.response + b"\x00")


def test_read_coils_byte_count_rounds_up_to_whole_bytes():
    # 6.1: "If the returned output quantity is not a multiple of eight, the remaining bits in
    # the final data byte will be padded with zeros": 8 coils -> 1 byte, 9 -> 2 bytes.
    assert reply_matches(bytes.fromhex("01 00 00 00 08"), bytes.fromhex("01 01 FF"))
    assert not reply_matches(bytes.fromhex("01 00 00 00 09"), bytes.fromhex("01 01 FF"))
    assert reply_matches(bytes.fromhex("01 00 00 00 09"), bytes.fromhex("01 02 FF 01"))


@pytest.mark.parametrize("label", ["FC05", "FC06", "FC0F", "FC10",
                                   "VPG05", "VPG06", "VPG0F"])
@pytest.mark.parametrize("index", [1, 2, 3, 4])
def test_write_reply_that_does_not_echo_address_and_value_or_quantity(label, index):
    pair = _pair(label)
    wrong = _with(pair.response, index, pair.response[index] ^ 0x01)
    assert not reply_matches(pair.request, wrong)


@pytest.mark.parametrize("label", ["FC05", "FC06", "FC0F", "FC10"])
def test_write_reply_of_the_wrong_size(label):
    pair = _pair(label)
    assert not reply_matches(pair.request, pair.response[:4])
    assert not reply_matches(pair.request, pair.response + b"\x00")


def test_exception_pdu():
    assert pdu.exception_pdu(0x03, pdu.GATEWAY_TARGET_FAILED) == b"\x83\x0B"
    assert pdu.exception_pdu(0x2B, pdu.GATEWAY_PATH_UNAVAILABLE) == b"\xAB\x0A"


def test_mask_write_reply_that_does_not_echo_the_request():
    pair = _pair("FC16")
    assert not reply_matches(pair.request, _with(pair.response, 6, 0x24))
