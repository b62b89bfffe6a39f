"""RTU frame lengths (mbgw.line.native.rtu_request_length / rtu_reply_length) for every public
function code, from the PDU layouts of the Modbus Application Protocol V1.1b3, section 6.

An RTU ADU is address + PDU + 2 CRC bytes.  The length functions never look at the CRC, so
frames built here from published PDUs carry two filler bytes in its place.
"""
import pytest

from mbgw.line import native
from tests.unit.vectors import CHECK_VECTORS, PDU_PAIRS

ADDRESS = b"\x11"
CRC_FILLER = b"\x00\x00"
UNKNOWN = native.LEN_UNKNOWN
PAIR_IDS = [p.label for p in PDU_PAIRS]

# How many ADU bytes must have arrived before the length can be told (address = byte 0),
# read off the section 6 layouts: where the byte count sits, or just the function code.
REQUEST_KNOWN_AT = {
    0x01: 2, 0x02: 2, 0x03: 2, 0x04: 2, 0x05: 2, 0x06: 2,   # fixed: address .. quantity/value
    0x07: 2, 0x0B: 2, 0x0C: 2, 0x11: 2,                     # function code only
    0x08: 4,                                                # the sub-function decides
    0x0F: 7, 0x10: 7,                                       # byte count after address, quantity
    0x14: 3, 0x15: 3,                                       # byte count right after the code
    0x16: 2,
    0x17: 11,                                               # write byte count after 4 words
    0x18: 2,
    0x2B: 3,                                                # the MEI type decides
}
REPLY_KNOWN_AT = {
    0x01: 3, 0x02: 3, 0x03: 3, 0x04: 3, 0x0C: 3, 0x11: 3, 0x14: 3, 0x15: 3, 0x17: 3,
    0x05: 2, 0x06: 2, 0x07: 2, 0x08: 2, 0x0B: 2, 0x0F: 2, 0x10: 2, 0x16: 2,
    0x18: 4,                                                # two-byte byte count
}


def _request_adu(pair) -> bytes:
    return ADDRESS + pair.request + CRC_FILLER


def _reply_adu(pair) -> bytes:
    return ADDRESS + pair.response + CRC_FILLER


def _fed_byte_by_byte(length_of, frame: bytes) -> list[int]:
    return [length_of(frame[:n]) for n in range(len(frame) + 1)]


def _assert_known_from(answers: list[int], known_at: int, length: int) -> None:
    """0 ("need more bytes") for every shorter prefix, then `length` from known_at on."""
    assert answers[:known_at] == [0] * known_at
    assert answers[known_at:] == [length] * (len(answers) - known_at)


def _is_return_query_data(pdu: bytes) -> bool:
    return pdu[0] == 0x08 and pdu[1:3] == b"\x00\x00"


# --- requests ---------------------------------------------------------------------------

@pytest.mark.parametrize("pair", PDU_PAIRS, ids=PAIR_IDS)
def test_request_length_of_published_request(pair):
    adu = _request_adu(pair)
    expected = UNKNOWN if _is_return_query_data(pair.request) else len(adu)
    assert native.rtu_request_length(adu) == expected


@pytest.mark.parametrize("pair", PDU_PAIRS, ids=PAIR_IDS)
def test_request_fed_byte_by_byte_needs_more_bytes_until_the_length_field(pair):
    adu = _request_adu(pair)
    expected = UNKNOWN if _is_return_query_data(pair.request) else len(adu)
    answers = _fed_byte_by_byte(native.rtu_request_length, adu)
    _assert_known_from(answers, REQUEST_KNOWN_AT[pair.request[0]], expected)


@pytest.mark.parametrize("pdu", [
    "11",                # 6.13 Report Server ID: function code only
    "08 00 01 00 00",    # 6.8 Diagnostics 01 Restart Communications Option, data 00 00
    "08 00 04 00 00",    # 6.8 Diagnostics 04 Force Listen Only Mode
    "08 00 0A 00 00",    # 6.8 Diagnostics 0A Clear Counters and Diagnostic Register
    "08 00 0B 00 00",    # 6.8 Diagnostics 0B Return Bus Message Count
    "2B 0E 04 01",       # 6.21 Read Device ID, individual access to object 01
])
def test_request_length_from_the_spec_layout(pdu):
    adu = ADDRESS + bytes.fromhex(pdu) + CRC_FILLER
    assert native.rtu_request_length(adu) == len(adu)


def test_return_query_data_request_is_framed_by_silence_whatever_its_size():
    # 6.8 sub-function 00: "The data passed in the request data field is to be returned".
    for data in (b"", b"\xA5\x37", bytes(range(20))):
        adu = ADDRESS + b"\x08\x00\x00" + data + CRC_FILLER
        assert native.rtu_request_length(adu) == UNKNOWN


def test_write_multiple_registers_request_with_the_largest_byte_count():
    # 6.12: at most 123 registers, byte count 246 -> ADU 1 + 6 + 246 + 2 = 255.
    head = ADDRESS + bytes.fromhex("10 00 00 00 7B F6")
    assert native.rtu_request_length(head) == 255


def test_read_device_id_request_with_another_mei_type_is_framed_by_silence():
    # 6.20: MEI type 0x0D is CANopen General Reference, whose length the PDU does not tell.
    assert native.rtu_request_length(ADDRESS + bytes.fromhex("2B 0D 00 00 00")) == UNKNOWN
    assert native.rtu_request_length(ADDRESS + b"\x2B") == 0


@pytest.mark.parametrize("function", [65, 66, 72, 100, 108, 110, 0x70, 0x7F])
def test_request_with_user_defined_or_unassigned_function_is_framed_by_silence(function):
    assert native.rtu_request_length(ADDRESS) == 0
    assert native.rtu_request_length(ADDRESS + bytes((function,))) == UNKNOWN
    assert native.rtu_request_length(ADDRESS + bytes((function, 1, 2, 3))) == UNKNOWN


def test_request_needs_address_and_function_code():
    assert native.rtu_request_length(b"") == 0
    assert native.rtu_request_length(b"\x11") == 0


# --- replies ----------------------------------------------------------------------------

@pytest.mark.parametrize("pair", PDU_PAIRS, ids=PAIR_IDS)
def test_reply_length_of_published_response(pair):
    request = ADDRESS + pair.request
    reply = _reply_adu(pair)
    assert native.rtu_reply_length(len(request), reply) == len(reply)


@pytest.mark.parametrize("pair", [p for p in PDU_PAIRS if p.response[0] != 0x2B],
                         ids=[p.label for p in PDU_PAIRS if p.response[0] != 0x2B])
def test_reply_fed_byte_by_byte_needs_more_bytes_until_the_length_field(pair):
    request_len = len(ADDRESS + pair.request)
    reply = _reply_adu(pair)
    function = pair.response[0]
    known_at = 2 if function & 0x80 else REPLY_KNOWN_AT[function]
    answers = _fed_byte_by_byte(lambda prefix: native.rtu_reply_length(request_len, prefix), reply)
    _assert_known_from(answers, known_at, len(reply))


VPGATE = [v for v in CHECK_VECTORS if v.source.startswith("VPGate")]


@pytest.mark.parametrize("vector", VPGATE, ids=[v.where for v in VPGATE])
def test_published_rtu_frame_with_its_crc_is_measured_whole(vector):
    """The VPGate appendix A frames exactly as on the wire; their requests are 6 bytes."""
    frame = vector.frame + vector.crc_wire
    assert "request" in vector.source or "response" in vector.source
    if "request" in vector.source:
        assert native.rtu_request_length(frame) == len(frame)
    if "response" in vector.source:
        assert native.rtu_reply_length(6, frame) == len(frame)


def test_read_device_identification_reply_is_measured_object_by_object():
    pair = next(p for p in PDU_PAIRS if p.label == "FC2B/0E")
    reply = _reply_adu(pair)
    assert len(reply) == 34                    # address + bytes 0-30 of the manual + CRC
    answers = _fed_byte_by_byte(lambda prefix: native.rtu_reply_length(6, prefix), reply)
    # ADU offsets: 7 object count; object 0 length at 9, object 1 length at 18, object 2
    # length at 27.  The length is known once the last object's length byte is in.
    _assert_known_from(answers, 28, 34)


def test_read_device_identification_reply_without_objects():
    # 6.21 layout: 2B 0E code conformity more-follows next-object number-of-objects(0).
    reply = ADDRESS + bytes.fromhex("2B 0E 01 01 00 00 00") + CRC_FILLER
    answers = _fed_byte_by_byte(lambda prefix: native.rtu_reply_length(6, prefix), reply)
    _assert_known_from(answers, 8, 10)


def test_reply_to_another_mei_type_is_framed_by_silence():
    reply = ADDRESS + bytes.fromhex("2B 0D 00 01 02 03")
    assert native.rtu_reply_length(6, reply[:2]) == 0
    assert native.rtu_reply_length(6, reply[:3]) == UNKNOWN
    assert native.rtu_reply_length(6, reply) == UNKNOWN


@pytest.mark.parametrize("function", [65, 66, 72, 100, 108, 110, 0x70, 0x7F])
def test_reply_with_user_defined_or_unassigned_function_is_framed_by_silence(function):
    assert native.rtu_reply_length(4, ADDRESS) == 0
    assert native.rtu_reply_length(4, ADDRESS + bytes((function,))) == UNKNOWN
    assert native.rtu_reply_length(4, ADDRESS + bytes((function, 3, 1, 2, 3))) == UNKNOWN


@pytest.mark.parametrize("function", [0x01, 0x03, 0x08, 0x14, 0x17, 0x18, 0x2B, 108])
def test_exception_reply_is_five_bytes_for_any_function(function):
    # 7: the function code with its MSB set, then one exception code.
    reply = ADDRESS + bytes((function | 0x80, 0x02)) + CRC_FILLER
    answers = _fed_byte_by_byte(lambda prefix: native.rtu_reply_length(8, prefix), reply)
    _assert_known_from(answers, 2, 5)


def test_diagnostics_reply_echoes_the_request_length():
    # 6.8: the normal response to Return Query Data echoes the request.
    for data in (b"\xA5\x37", b"\x01\x02\x03\x04", bytes(40)):
        request = ADDRESS + b"\x08\x00\x00" + data
        reply = request + CRC_FILLER
        assert native.rtu_reply_length(len(request), reply[:2]) == len(reply)


def test_read_registers_reply_with_the_largest_byte_count():
    # 6.3: at most 125 registers, byte count 250 -> ADU 1 + 2 + 250 + 2 = 255.
    assert native.rtu_reply_length(6, ADDRESS + b"\x03\xFA") == 255


def test_read_coils_reply_length_follows_the_byte_count_not_the_request():
    # The reply length comes from the reply itself; whether it fits the request is
    # reply_matches's business (csrc/match.c).
    assert native.rtu_reply_length(6, ADDRESS + b"\x01\x01") == 6
    assert native.rtu_reply_length(6, ADDRESS + b"\x01\x00") == 5


def test_read_fifo_reply_with_the_largest_queue():
    # 6.18: at most 31 registers -> byte count 2 + 62 = 64 -> ADU 1 + 3 + 64 + 2 = 70.
    assert native.rtu_reply_length(4, ADDRESS + b"\x18\x00") == 0
    assert native.rtu_reply_length(4, ADDRESS + b"\x18\x00\x40") == 70


def test_report_server_id_reply_from_the_spec_layout():
    # 6.13: function code, byte count, server id (device specific), run indicator FF.
    reply = ADDRESS + bytes.fromhex("11 02 42 FF") + CRC_FILLER
    answers = _fed_byte_by_byte(lambda prefix: native.rtu_reply_length(4, prefix), reply)
    _assert_known_from(answers, 3, 7)


def test_reply_needs_address_and_function_code():
    assert native.rtu_reply_length(8, b"") == 0
    assert native.rtu_reply_length(8, b"\x11") == 0
