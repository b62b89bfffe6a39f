"""The table's identity functions (csrc/table_ident.c through mbgw.table.memory): FC 8
sub-functions 0 and 10-18, FC 17 and FC 43/14.  Expected bytes are written here from the
Modbus Application Protocol V1.1b3 (sections 6.8, 6.13, 6.21, their examples where they have
them) and the Modbus over serial line specification V1.02 (6.1), never produced by mbgw."""
import socket

import pytest

import mbgw
from mbgw.config.model import SerialConfig, SlaveConfig
from mbgw.table import identity
from mbgw.table.memory import IDENTITY_OBJECT_MAX, Table, TableError
from tests.unit.vectors import PDU_PAIRS

H = bytes.fromhex
# the objects of the spec's example in 6.21 (VendorName, ProductCode, MajorMinorRevision)
SPEC_OBJECTS = [b"Company identification", b"Product code XX", b"V2.11",
                b"", b"", b"", b""]


@pytest.fixture
def table():
    t = Table()
    t.set_identity(SPEC_OBJECTS, b"mbgw\xff0.3.0")
    return t


def ask(table: Table, hex_pdu: str) -> str:
    reply = table.answer(H(hex_pdu))
    assert reply is not None
    return reply.hex(" ")


def text(value: bytes) -> str:
    return value.hex(" ")


# --- FC 43/14 ---

def test_fc43_spec_example_basic_stream(table):
    # 6.21's example: 2B 0E 01 01 00 00 03, then objects 0-2 as (id, length, value); the
    # conformity level is mbgw's 0x83 (basic, regular, extended; stream and individual).
    # The spec prints 0D as the length of "Product code XX", which has 15 bytes: 0F.
    assert ask(table, "2b 0e 01 00") == (
        "2b 0e 01 83 00 00 03 00 16 " + text(b"Company identification")
        + " 01 0f " + text(b"Product code XX") + " 02 05 " + text(b"V2.11"))


def test_fc43_published_response_toshiba_vf_s15(table):
    """tests/vectors/pdu_pairs.txt FC2B/0E: a device's basic stream, its conformity level
    (02) replaced by mbgw's 0x83."""
    (pair,) = [p for p in PDU_PAIRS if p.label == "FC2B/0E"]
    table.set_identity([b"TOSHIBA", b"PNE001Z", b"0201", b"", b"", b"", b""], b"")
    expected = bytearray(pair.response)
    expected[3] = 0x83
    assert table.answer(pair.request) == bytes(expected)


def test_fc8_published_return_query_data(table):
    (pair,) = [p for p in PDU_PAIRS if p.label == "FC08"]
    assert table.answer(pair.request) == pair.response


def test_fc43_regular_stream_has_objects_0_to_6(table):
    table.set_identity([b"a", b"b", b"c", b"d", b"e", b"f", b"g"], b"")
    assert ask(table, "2b 0e 02 00") == ("2b 0e 02 83 00 00 07 00 01 61 01 01 62 02 01 63 "
                                         "03 01 64 04 01 65 05 01 66 06 01 67")
    # extended: the regular objects, there are no private ones
    assert ask(table, "2b 0e 03 00").startswith("2b 0e 03 83 00 00 07 00 01 61")


def test_fc43_stream_begins_at_the_object_asked_or_at_0_outside_the_category(table):
    assert ask(table, "2b 0e 01 02") == "2b 0e 01 83 00 00 01 02 05 " + text(b"V2.11")
    # object 4 is no basic object: as if object 0 were asked (6.21)
    assert ask(table, "2b 0e 01 04").startswith("2b 0e 01 83 00 00 03 00 16")
    assert ask(table, "2b 0e 02 80").startswith("2b 0e 02 83 00 00 07 00 16")


def test_fc43_individual_access(table):
    assert ask(table, "2b 0e 04 01") == "2b 0e 04 83 00 00 01 01 0f " + text(b"Product code XX")
    # an object the device does not have: exception 02 (6.21)
    assert ask(table, "2b 0e 04 07") == "ab 02"
    assert ask(table, "2b 0e 04 80") == "ab 02"


def test_fc43_more_follows_when_the_objects_do_not_fit(table):
    long = [bytes([0x41 + n]) * 100 for n in range(7)]
    table.set_identity(long, b"")
    first = table.answer(H("2b 0e 02 00"))
    # 7 header bytes + two objects of 2 + 100 fill 211 bytes; a third would pass 253
    assert first[:7] == H("2b 0e 02 83 ff 02 02")
    assert first[7:9] == H("00 64") and first[9:109] == b"A" * 100
    assert first[109:111] == H("01 64") and len(first) == 211
    # the client asks again from the next object id
    assert table.answer(H("2b 0e 02 02"))[:9] == H("2b 0e 02 83 ff 04 02 02 64")
    assert table.answer(H("2b 0e 02 06")) == H("2b 0e 02 83 00 00 01 06 64") + b"G" * 100


@pytest.mark.parametrize("request_hex, reply", [
    ("2b 0e 00 00", "ab 03"),         # read device id code 0
    ("2b 0e 05 00", "ab 03"),
    ("2b 0e 01", "ab 03"),             # too short
    ("2b 0e 01 00 00", "ab 03"),       # too long
    ("2b 0d 01 00", "ab 01"),          # another MEI type
])
def test_fc43_bad_requests(table, request_hex, reply):
    assert ask(table, request_hex) == reply


def test_identity_objects_have_a_bound(table):
    with pytest.raises(TableError, match="object 6"):
        table.set_identity([b""] * 6 + [b"x" * (IDENTITY_OBJECT_MAX + 1)], b"")
    with pytest.raises(TableError, match="7"):
        table.set_identity([b""] * 6, b"")


# --- FC 17 ---

def test_fc17_byte_count_server_id_run_indicator_and_data(table):
    # 6.13: 11, byte count, server id, run indicator (FF on), additional data
    assert ask(table, "11") == "11 0a 6d 62 67 77 ff 30 2e 33 2e 30"
    assert ask(table, "11 00") == "91 03"


def test_the_gateway_identity():
    t = Table()
    identity.fill(t, SlaveConfig(serial=SerialConfig("/dev/ttyX")), "slave")
    assert t.answer(H("11")) == H("11 0a") + b"mbgw\xff" + mbgw.__version__.encode()
    host = socket.gethostname().encode()
    assert t.answer(H("2b 0e 04 06")) == H("2b 0e 04 83 00 00 01 06") + bytes([len(host)]) + host
    assert t.answer(H("2b 0e 04 00")) == H("2b 0e 04 83 00 00 01 00 04") + b"mbgw"


# --- FC 8 ---

def test_fc8_spec_example_return_query_data(table):
    # 6.8.1 sub-function 00: the request looped back whole
    assert ask(table, "08 00 00 a5 37") == "08 00 00 a5 37"
    assert ask(table, "08 00 00 01 02 03 04") == "08 00 00 01 02 03 04"


def test_fc8_counters_count_since_the_last_clear(table):
    assert ask(table, "08 00 0a 00 00") == "08 00 0a 00 00"       # clear: echoed
    for _ in range(3):
        ask(table, "03 00 00 00 01")
    ask(table, "03 00 00 00 00")                                   # exception 03
    table.answer(H("06 00 05 00 01"), broadcast=True)              # no response
    # 11 bus message count: the 5 above and this one
    assert ask(table, "08 00 0b 00 00") == "08 00 0b 00 06"
    assert ask(table, "08 00 0c 00 00") == "08 00 0c 00 00"       # 12 communication errors
    assert ask(table, "08 00 0d 00 00") == "08 00 0d 00 01"       # 13 exception errors
    assert ask(table, "08 00 0e 00 00") == "08 00 0e 00 09"       # 14 server messages
    assert ask(table, "08 00 0f 00 00") == "08 00 0f 00 01"       # 15 no response
    for sub in ("10", "11", "12"):                                  # 16 NAK, 17 busy, 18 overrun
        assert ask(table, f"08 00 {sub} 00 00") == f"08 00 {sub} 00 00"
    ask(table, "08 00 0a 00 00")
    assert ask(table, "08 00 0b 00 00") == "08 00 0b 00 01"


def test_fc8_counts_bad_frames_as_communication_errors(table):
    table.answer_mbap_into(H("00 01 00 00 00 09 01 03 00 00 00 01"))   # length field wrong
    assert table.diagnostics()["bus_errors"] == 1
    assert table.diagnostics()["bus_messages"] == 1


@pytest.mark.parametrize("request_hex, reply", [
    ("08 00 01 00 00", "88 01"),        # restart communications: not supported
    ("08 00 04 00 00", "88 01"),        # listen only
    ("08 00 13 00 00", "88 01"),
    ("08 00 0b 00 01", "88 03"),        # a counter's data field is 0000
    ("08 00 0b", "88 03"),
    ("08 00", "88 03"),
])
def test_fc8_bad_requests(table, request_hex, reply):
    assert ask(table, request_hex) == reply


# --- whatever the function lists say ---

def test_identity_functions_answer_on_a_responder_with_no_function(table):
    gateway = table.responder(())
    assert bytes(gateway.answer(H("03 00 00 00 01"))) == H("83 01")
    assert bytes(gateway.answer(H("08 00 00 12 34"))) == H("08 00 00 12 34")
    assert bytes(gateway.answer(H("11")))[:2] == H("11 0a")
    frame = H("00 07 00 00 00 05 fe 2b 0e 04 02")
    assert bytes(gateway.answer_mbap(frame)) == \
        H("00 07 00 00 00 0f fe 2b 0e 04 83 00 00 01 02 05") + b"V2.11"
    # the refusal counts as an exception reply
    assert table.diagnostics()["exceptions"] == 1
    assert table.diagnostics()["bus_messages"] == 4


def test_the_gateway_unit_answers_identity_functions_only(table):
    responder = table.responder()
    assert bytes(responder.answer_identity(H("03 00 00 00 01"))) == H("83 01")
    assert bytes(responder.answer_identity(H("08 00 00 12 34"))) == H("08 00 00 12 34")
    assert bytes(responder.answer_identity(H("08 00 0d 00 00"))) == H("08 00 0d 00 01")
