"""The exchange table (csrc/table.c through mbgw.table.memory): every function, every exception,
the bit mapping, broadcast, the MBAP form, counters, and no torn reads under concurrent writes.
Expected bytes are written here from the Modbus Application Protocol V1.1b3 (its section 6
examples where it has them), never produced by mbgw's code."""
import os
import struct
import threading

import pytest

from mbgw.table.memory import WATCHES, Table, TableError

H = bytes.fromhex


@pytest.fixture
def table():
    return Table()


def ask(table: Table, hex_pdu: str) -> str:
    reply = table.answer(H(hex_pdu))
    assert reply is not None
    return reply.hex(" ")


# --- the spec's own examples (section 6), values stored first ---

def test_fc1_spec_example_bits_from_registers(table):
    # coils 20-38 (bit addresses 19-37) of the spec's reply 01 03 CD 6B 05, as register bits:
    # bits 19-31 are bits 3-15 of register 1: 1,0,1,1,0,0,1,1 (CD) 1,1,0,1,0 (6B low) -> 0x5E68;
    # bits 32-37 are bits 0-5 of register 2: 1,1,0 (6B high) 1,0,1 (05) -> 0x002B
    table.write(1, [0x5E68, 0x002B])
    assert ask(table, "01 00 13 00 13") == "01 03 cd 6b 05"


def test_fc2_spec_example(table):
    # inputs 197-218 (bit addresses 196-217) of the reply 02 03 AC DB 35: register 12 bits
    # 4-15 = 0,0,1,1,0,1,0,1 (AC) 1,1,0,1 (DB low) -> 0xBAC0; register 13 bits 0-9 =
    # 1,0,1,1 (DB high) 1,0,1,0,1,1 (35) -> 0x035D
    table.write(12, [0xBAC0, 0x035D])
    assert ask(table, "02 00 c4 00 16") == "02 03 ac db 35"


def test_fc3_spec_example(table):
    table.write(0x6B, [0x022B, 0x0000, 0x0064])
    assert ask(table, "03 00 6b 00 03") == "03 06 02 2b 00 00 00 64"


def test_fc4_reads_the_same_registers_as_fc3(table):
    table.write(8, [0x000A])
    assert ask(table, "04 00 08 00 01") == "04 02 00 0a"
    assert ask(table, "03 00 08 00 01") == "03 02 00 0a"


def test_fc5_spec_example_echoes_and_sets_the_bit(table):
    assert ask(table, "05 00 ac ff 00") == "05 00 ac ff 00"
    assert table.read(10) == [0x1000]          # bit 172 = bit 12 of register 10
    assert ask(table, "05 00 ac 00 00") == "05 00 ac 00 00"
    assert table.read(10) == [0]


def test_fc6_spec_example(table):
    assert ask(table, "06 00 01 00 03") == "06 00 01 00 03"
    assert table.read(1) == [3]


def test_fc15_spec_example(table):
    # coils 20-29 (bits 19-28) = CD, 01: bits 3-12 of register 1 = 1,0,1,1,0,0,1,1,1,0 -> 0x0E68
    assert ask(table, "0f 00 13 00 0a 02 cd 01") == "0f 00 13 00 0a"
    assert table.read(1, 2) == [0x0E68, 0]


def test_fc15_clears_bits_and_keeps_the_others(table):
    table.write(0, [0xFFFF])
    assert ask(table, "0f 00 04 00 04 01 05") == "0f 00 04 00 04"   # bits 4-7 = 1,0,1,0
    assert table.read(0) == [0xFF5F]


def test_fc16_spec_example(table):
    assert ask(table, "10 00 01 00 02 04 00 0a 01 02") == "10 00 01 00 02"
    assert table.read(1, 2) == [0x000A, 0x0102]


def test_fc23_spec_example(table):
    table.write(3, [0x00FE, 0x0ACD, 0x0001, 0x0003, 0x000D, 0x00FF])
    assert ask(table, "17 00 03 00 06 00 0e 00 03 06 00 ff 00 ff 00 ff") == \
        "17 0c 00 fe 0a cd 00 01 00 03 00 0d 00 ff"
    assert table.read(14, 3) == [0xFF, 0xFF, 0xFF]


def test_fc23_writes_before_it_reads(table):
    assert ask(table, "17 00 0e 00 03 00 0e 00 03 06 00 01 00 02 00 03") == \
        "17 06 00 01 00 02 00 03"


def test_bits_reach_registers_0_to_0x0fff(table):
    table.write(0x0FFF, [0x8000])
    assert ask(table, "01 ff ff 00 01") == "01 01 01"   # bit 65535 = bit 15 of 0x0FFF
    assert ask(table, "05 00 00 ff 00") == "05 00 00 ff 00"
    assert table.read(0) == [1]
    assert table.read_bits(65535) == [1]
    assert table.read_bits(0, 3) == [1, 0, 0]


def test_read_bits_of_2000_packs_250_bytes(table):
    table.write(0, [0x0001] * 125)
    reply = H(ask(table, "01 00 00 07 d0"))
    assert reply[:2] == H("01 fa") and len(reply) == 252
    assert reply[2:] == H("01 00") * 125


# --- FC 7 ---

def test_fc7_status_byte(table):
    assert ask(table, "07") == "07 00"
    table.set_flags(line_down=True)
    assert ask(table, "07") == "07 01"
    table.set_flags(scenario_error=True)
    assert ask(table, "07") == "07 03"
    table.set_flags(line_down=False, scenario_error=False)
    assert ask(table, "07") == "07 00"


def test_fc7_reads_the_watched_down_table_at_each_request(table):
    down = bytearray(256)
    table.watch_down(down)
    assert ask(table, "07") == "07 00"
    down[17] = 1
    assert ask(table, "07") == "07 04"
    table.set_flags(line_down=True)
    assert ask(table, "07") == "07 05"
    down[17] = 0
    assert ask(table, "07") == "07 01"
    down[200] = 1
    table.watch_down(None)
    assert ask(table, "07") == "07 01"


# --- exceptions, in the order the table checks them ---

@pytest.mark.parametrize("request_hex, reply", [
    ("08 00 01 00 00", "88 01"),          # diagnostics: restart, a sub-function it lacks
    ("2b 0d 00 00", "ab 01"),              # MEI type 13 (CANopen), not device identification
    ("14 07 06 00 04 00 01 00 02", "94 01"),
    ("00", "80 01"),
])
def test_unknown_function_is_0x01(table, request_hex, reply):
    assert ask(table, request_hex) == reply


def test_disabled_function_is_0x01_before_anything_else(table):
    table.set_functions([3])
    assert ask(table, "04 00 00 00 01") == "84 01"
    assert ask(table, "06 80 00 00 01") == "86 01"          # even a config-zone write
    assert ask(table, "10 00 00 00 00 00") == "90 01"       # even a bad quantity
    assert ask(table, "03 00 00 00 01") == "03 02 00 00"


def test_serial_functions_are_a_list_of_their_own(table):
    """VPGate 3.7: the serial slave's list beside the TCP server's; each side refuses, 0x01,
    what the other may do, and a refused write changes nothing."""
    table.set_functions([3, 4], serial_functions=[3, 6, 16])
    serial = table.responder([3, 6, 16])
    tcp = table.responder()
    assert bytes(serial.answer(bytes.fromhex("06 1000 beef"))).hex(" ") == "06 10 00 be ef"
    assert bytes(tcp.answer(bytes.fromhex("06 1000 0001"))).hex(" ") == "86 01"
    assert bytes(serial.answer(bytes.fromhex("04 0000 0001"))).hex(" ") == "84 01"
    assert bytes(tcp.answer(bytes.fromhex("04 0000 0001"))).hex(" ") == "04 02 00 00"
    # the MBAP path the TCP server takes: tid, protocol, length 3, unit kept
    frame = bytes.fromhex("12 34 00 00 00 06 ff 06 1000 0002")
    assert bytes(tcp.answer_mbap(frame)).hex(" ") == "12 34 00 00 00 03 ff 86 01"
    assert tcp.answer_mbap(bytes.fromhex("12 34 00 00 00 06 00 06 1000 0002"), True) is None
    assert table.read(0x1000) == [0xBEEF]
    assert bytes(tcp.answer_mbap(bytes.fromhex("00 01 00 00 00 06 01 03 1000 0001"))).hex(
        " ") == "00 01 00 00 00 05 01 03 02 be ef"
    assert tcp.answer_mbap_into(bytes.fromhex("00 01 00 01 00 06 01 06 1000 0002")) < 0
    table.set_functions([3, 4])                    # one list again: both sides answer it
    assert bytes(tcp.answer(bytes.fromhex("04 0000 0001"))).hex(" ") == "04 02 00 00"


def test_set_functions_refuses_what_the_table_cannot_answer(table):
    with pytest.raises(TableError, match="function 8"):
        table.set_functions([3, 8])


@pytest.mark.parametrize("fc, limit", [(1, 2000), (2, 2000), (3, 125), (4, 125)])
def test_read_quantity_limits_at_both_edges(table, fc, limit):
    def read(quantity):
        return ask(table, f"{fc:02x} 00 00 {quantity:04x}")
    err = f"{fc | 0x80:02x} 03"
    assert read(0) == err
    assert read(1) != err
    assert read(limit) != err
    assert read(limit + 1) == err
    assert read(0xFFFF) == err


def _fc15(quantity: int, nbytes: int | None = None, data: bytes | None = None) -> str:
    nbytes = (quantity + 7) // 8 if nbytes is None else nbytes
    data = bytes(nbytes) if data is None else data
    return (struct.pack(">BHHB", 0x0F, 0, quantity, nbytes & 0xFF) + data).hex()


def _fc16(address: int, values: list[int], nbytes: int | None = None,
          quantity: int | None = None) -> str:
    quantity = len(values) if quantity is None else quantity
    nbytes = 2 * len(values) if nbytes is None else nbytes
    return (struct.pack(">BHHB", 0x10, address, quantity, nbytes & 0xFF)
            + struct.pack(f">{len(values)}H", *values)).hex()


def _fc23(read_at: int, read_n: int, write_at: int, values: list[int],
          nbytes: int | None = None, write_n: int | None = None) -> str:
    write_n = len(values) if write_n is None else write_n
    nbytes = 2 * len(values) if nbytes is None else nbytes
    return (struct.pack(">BHHHHB", 0x17, read_at, read_n, write_at, write_n, nbytes & 0xFF)
            + struct.pack(f">{len(values)}H", *values)).hex()


def test_fc15_quantity_limits(table):
    assert ask(table, _fc15(0, 0)) == "8f 03"
    assert ask(table, _fc15(1)) == "0f 00 00 00 01"
    assert ask(table, _fc15(1968)) == "0f 00 00 07 b0"
    assert ask(table, _fc15(1969)) == "8f 03"


def test_fc16_quantity_limits(table):
    assert ask(table, _fc16(0, [])) == "90 03"
    assert ask(table, _fc16(0, [1])) == "10 00 00 00 01"
    assert ask(table, _fc16(0, [1] * 123)) == "10 00 00 00 7b"
    assert ask(table, _fc16(0, [1] * 124)) == "90 03"


def test_fc23_quantity_limits(table):
    assert ask(table, _fc23(0, 0, 0, [1])) == "97 03"
    assert ask(table, _fc23(0, 125, 0, [1]))[:5] == "17 fa"
    assert ask(table, _fc23(0, 126, 0, [1])) == "97 03"
    assert ask(table, _fc23(0, 1, 0, [])) == "97 03"
    assert ask(table, _fc23(0, 1, 0, [7] * 121)) == "17 02 00 07"
    assert ask(table, _fc23(0, 1, 0, [7] * 122)) == "97 03"


@pytest.mark.parametrize("request_hex, reply", [
    (_fc15(10, 1, b"\xff"), "8f 03"),              # byte count for 8 bits, 10 asked
    (_fc15(10, 2, b"\xff"), "8f 03"),              # byte count right, one byte missing
    (_fc15(10, 2, b"\xff\x03\x00"), "8f 03"),      # a byte too many
    (_fc16(0, [1, 2], nbytes=3), "90 03"),
    (_fc16(0, [1, 2], quantity=3), "90 03"),
    (_fc16(0, [1, 2]) + "00", "90 03"),
    ("10 00 00 00 02 04 00 01 00", "90 03"),       # a value cut short
    ("10 00 00 00", "90 03"),
    (_fc23(0, 1, 0, [1, 2], nbytes=2), "97 03"),
    (_fc23(0, 1, 0, [1, 2], write_n=1), "97 03"),
    ("17 00 00 00 01 00 00 00 01 02 00", "97 03"),
    ("03 00 00 00 01 00", "83 03"),                # a byte too many
    ("03 00 00 00", "83 03"),
    ("01 00 00", "81 03"),
    ("06 00 01 00", "86 03"),
    ("05 00 01 ff 00 00", "85 03"),
    ("07 00", "87 03"),
])
def test_length_or_byte_count_mismatch_is_0x03(table, request_hex, reply):
    assert ask(table, request_hex) == reply
    assert table.read(0, 3) == [0, 0, 0]


@pytest.mark.parametrize("value", ["00 01", "ff ff", "00 ff", "12 34", "ff 01"])
def test_fc5_value_other_than_0000_or_ff00_is_0x03(table, value):
    assert ask(table, f"05 00 00 {value}") == "85 03"
    assert table.read(0) == [0]


def test_quantity_is_checked_before_the_address(table):
    assert ask(table, "03 ff ff 00 00") == "83 03"
    assert ask(table, "03 ff ff 00 7e") == "83 03"
    assert ask(table, _fc16(0x8000, [1] * 124)) == "90 03"


@pytest.mark.parametrize("request_hex, reply", [
    ("01 ff ff 00 01", None),                 # bit 65535: the last
    ("01 ff ff 00 02", "81 02"),
    ("03 ff 83 00 7d", None),                 # 65411 + 125 = 65536: the last register
    ("03 ff 84 00 7d", "83 02"),
    ("04 ff ff 00 02", "84 02"),
    ("0f ff ff 00 02 01 03", "8f 02"),
    ("10 ff ff 00 02 04 00 01 00 02", "90 02"),
    ("17 ff ff 00 02 00 00 00 01 02 00 01", "97 02"),
    ("17 00 00 00 01 ff ff 00 02 04 00 01 00 02", "97 02"),
])
def test_address_plus_quantity_beyond_65536_is_0x02(table, request_hex, reply):
    answer = ask(table, request_hex)
    if reply is None:
        assert answer[:2] == request_hex[:2]
    else:
        assert answer == reply


def test_fc2_beyond_by_one_bit(table):
    assert ask(table, "02 f8 30 07 d0")[:2] == "02"      # 63536 + 2000 = 65536
    assert ask(table, "02 f8 31 07 d0") == "82 02"


@pytest.mark.parametrize("request_hex, reply", [
    ("06 80 00 00 01", "86 02"),
    ("06 ff ff 00 01", "86 02"),
    ("10 7f ff 00 02 04 00 01 00 02", "90 02"),       # 0x7FFF is free, 0x8000 config
    ("10 80 10 00 01 02 00 01", "90 02"),
    ("17 00 00 00 01 7f ff 00 02 04 00 01 00 02", "97 02"),
    ("17 00 00 00 01 90 00 00 01 02 00 01", "97 02"),
])
def test_a_write_into_the_configuration_zone_is_0x02_and_writes_nothing(
        table, request_hex, reply):
    table.set_config(0x8000, [0x1111] * 32)
    before = table.read(0x7FFF, 1) + table.read(0x8000, 32)
    generation = table.persist_generation
    assert ask(table, request_hex) == reply
    assert table.read(0x7FFF, 1) + table.read(0x8000, 32) == before
    assert table.persist_generation == generation


def test_the_configuration_zone_reads_and_the_free_zone_takes_writes(table):
    table.set_config(0x8000, [0x6D62, 0x6777])          # "mbgw"
    assert ask(table, "03 80 00 00 02") == "03 04 6d 62 67 77"
    assert ask(table, "17 80 00 00 01 7f ff 00 01 02 12 34") == "17 02 6d 62"
    assert ask(table, "06 7f ff 00 05") == "06 7f ff 00 05"
    assert table.read(0x7FFF) == [5]


# --- broadcast ---

def test_broadcast_writes_and_gets_no_reply(table):
    assert table.answer(H("06 00 01 00 03"), broadcast=True) is None
    assert table.answer(H("10 00 02 00 02 04 00 0a 01 02"), broadcast=True) is None
    assert table.answer(H("05 00 40 ff 00"), broadcast=True) is None       # bit 0 of reg 4
    assert table.answer(H("0f 00 50 00 02 01 03"), broadcast=True) is None  # bits 0-1 of reg 5
    assert table.answer(H("17 00 00 00 01 00 06 00 01 02 00 07"), broadcast=True) is None
    assert table.read(1, 6) == [3, 0x000A, 0x0102, 1, 3, 7]


def test_broadcast_reads_and_bad_requests_are_ignored(table):
    for request_hex in ("03 00 00 00 01", "01 00 00 00 01", "07", "08 00 00 00 00",
                        "06 80 00 00 01", "10 00 00 00 02 03 00 01 00"):
        assert table.answer(H(request_hex), broadcast=True) is None
    assert table.read(0, 2) == [0, 0]
    assert table.read(0x8000) == [0]
    counts = table.counts()
    assert counts["requests_by_function"][3] == {"answered": 0, "exception": 0, "broadcast": 1}
    assert counts["requests_by_function"][8] == {"answered": 0, "exception": 0, "broadcast": 1}
    assert counts["exceptions_by_code"] == {}


# --- the MBAP form ---

def test_mbap_reply_keeps_tid_and_unit_and_sets_the_length():
    table = Table()
    table.write(0x6B, [0x022B, 0x0000, 0x0064])
    responder = table.responder()
    reply = responder.answer_mbap(H("12 34 00 00 00 06 fe 03 00 6b 00 03"))
    assert bytes(reply) == H("12 34 00 00 00 09 fe 03 06 02 2b 00 00 00 64")
    reply = responder.answer_mbap(H("ab cd 00 00 00 03 07 83 00"))    # FC 0x83: unknown
    assert bytes(reply) == H("ab cd 00 00 00 03 07 83 01")


def test_mbap_into_the_tables_own_buffer():
    table = Table()
    n = table.answer_mbap_into(bytearray(H("00 01 00 00 00 06 01 06 00 05 12 34")))
    assert n == 12
    assert bytes(table.reply_buffer[0:n]) == H("00 01 00 00 00 06 01 06 00 05 12 34")
    assert table.read(5) == [0x1234]


def test_mbap_broadcast_writes_and_gets_no_reply():
    table = Table()
    responder = table.responder()
    assert responder.answer_mbap(memoryview(H("00 02 00 00 00 06 00 06 00 05 00 09")),
                                 broadcast=True) is None
    assert table.read(5) == [9]


@pytest.mark.parametrize("frame_hex", [
    "00 01 00 01 00 06 01 03 00 00 00 01",     # protocol id 1
    "00 01 00 00 00 07 01 03 00 00 00 01",     # the length field says one byte more
    "00 01 00 00 00 01 01",                    # no PDU
    "00 01 00 00 00 ff 01 03" + " 00" * 253,   # the frame's length, but over 254
])
def test_mbap_header_that_does_not_fit_is_refused(frame_hex):
    table = Table()
    assert table.responder().answer_mbap_into(H(frame_hex)) < 0


# --- counters, persistence's generation, the operator's access ---

def test_counters_by_function_and_exception_code(table):
    ask(table, "03 00 00 00 01")
    ask(table, "03 00 00 00 01")
    ask(table, "03 00 00 00 00")
    ask(table, "06 80 00 00 01")
    ask(table, "08 00 01 00 00")
    table.answer(H("06 00 00 00 01"), broadcast=True)
    counts = table.counts()
    by_function = counts["requests_by_function"]
    assert by_function[3] == {"answered": 2, "exception": 1, "broadcast": 0}
    assert by_function[6] == {"answered": 0, "exception": 1, "broadcast": 1}
    assert by_function[8] == {"answered": 0, "exception": 1, "broadcast": 0}
    assert by_function[16] == {"answered": 0, "exception": 0, "broadcast": 0}
    assert set(by_function) == {1, 2, 3, 4, 5, 6, 7, 8, 15, 16, 23}
    assert counts["exceptions_by_code"] == {1: 1, 2: 1, 3: 1}
    table.reset_counts()
    counts = table.counts()
    assert counts["exceptions_by_code"] == {}
    assert by_function.keys() - counts["requests_by_function"].keys() == {8}


def test_persist_generation_counts_changes_to_outputs_and_free_zone_only(table):
    generation = table.persist_generation
    ask(table, "06 07 ff 00 01")                    # an input
    table.write(0, [5, 6])
    assert table.persist_generation == generation
    ask(table, "06 08 00 00 01")                    # the first output
    assert table.persist_generation == generation + 1
    ask(table, "06 08 00 00 01")                    # the same value: no change
    table.write(0x0800, [1])
    assert table.persist_generation == generation + 1
    ask(table, "10 7f fe 00 02 04 00 01 00 02")     # the end of the free zone
    assert table.persist_generation == generation + 2
    ask(table, "05 80 00 ff 00")                    # bit 0x8000 = bit 0 of register 0x0800
    assert table.read(0x0800) == [1] and table.persist_generation == generation + 2
    ask(table, "05 80 01 ff 00")
    assert table.read(0x0800) == [3] and table.persist_generation == generation + 3
    table.write(0x1000, [9])
    assert table.persist_generation == generation + 4


def test_operator_write_refuses_the_configuration_zone_and_writes_nothing(table):
    with pytest.raises(TableError, match="register 32768: the configuration zone"):
        table.write(0x7FFE, [1, 2, 3])
    assert table.read(0x7FFE, 2) == [0, 0]
    with pytest.raises(TableError, match="register 65535"):
        table.write(0xFFFF, [1])


def test_operator_access_beyond_the_table_or_bad_values(table):
    with pytest.raises(TableError, match="register 65535\\+2: beyond"):
        table.read(0xFFFF, 2)
    with pytest.raises(TableError, match="register -1"):
        table.read(-1)
    with pytest.raises(TableError, match="register 3: value 65536"):
        table.write(2, [1, 0x10000])
    with pytest.raises(TableError, match="bit 65535\\+2"):
        table.read_bits(0xFFFF, 2)
    with pytest.raises(TableError, match="register 16: not in the configuration zone"):
        table.set_config(16, [1])
    assert table.read(2, 2) == [0, 0]


# --- every request sees the table whole ---

def test_readers_never_see_a_torn_multi_register_write():
    """Two writers put 120 equal values with FC 16 (each write another value) while two
    readers read the range with FC 3 until the writers are done."""
    table = Table()
    writes_each = 20000
    writers_done = threading.Event()
    torn: list[bytes] = []
    failures: list[bytes] = []
    reads = [0, 0]

    def writer(first: int) -> None:
        responder = table.responder()
        for k in range(writes_each):
            value = (first + 2 * k) & 0xFFFF
            request = struct.pack(">BHHB", 0x10, 0x1000, 120, 240) + \
                struct.pack(">H", value) * 120
            reply = bytes(responder.answer(request))
            if reply != H("10 10 00 00 78"):
                failures.append(reply)

    def reader(index: int) -> None:
        responder = table.responder()
        request = H("03 10 00 00 78")
        while not writers_done.is_set():
            values = bytes(responder.answer(request))[2:]
            if values != values[:2] * 120:
                torn.append(values)
            reads[index] += 1

    writers = [threading.Thread(target=writer, args=(k,)) for k in (0, 1)]
    readers = [threading.Thread(target=reader, args=(k,)) for k in (0, 1)]
    for thread in readers + writers:
        thread.start()
    for thread in writers:
        thread.join()
    writers_done.set()
    for thread in readers:
        thread.join()
    assert not failures and not torn, (failures[:1], torn[:1])
    assert all(reads), reads
    assert table.persist_generation > writes_each


# ---- watches: what changed, for scenarios sent on change and transparent mode ----

def _signalled(fd: int) -> int:
    try:
        return os.eventfd_read(fd)
    except BlockingIOError:
        return 0


def test_a_watch_sees_a_changed_value_once_and_not_the_same_value_written_again():
    table = Table()
    fd = os.eventfd(0, os.EFD_NONBLOCK)
    try:
        watch = table.watch(0x0800, 4, fd)
        table.answer(bytes.fromhex("10 0800 0002 04 0001 0002"))     # FC 16 into it
        table.answer(bytes.fromhex("06 0803 0009"))                  # again, before the take
        assert _signalled(fd) == 1                                   # one wake-up for both
        assert table.take_change(watch, 4) == [1, 2, 0, 9]
        assert table.take_change(watch, 4) is None
        table.answer(bytes.fromhex("06 0800 0001"))                  # the same value
        table.answer(bytes.fromhex("06 0804 0001"))                  # just outside
        assert _signalled(fd) == 0 and table.take_change(watch, 4) is None
        table.answer(bytes.fromhex("05 8031 FF00"))                  # FC 5: bit 1 of 0x0803
        assert _signalled(fd) == 1 and table.take_change(watch, 4) == [1, 2, 0, 9 | 2]
        table.write(0x0801, [7])                                     # the operator's write
        assert table.take_change(watch, 4) == [1, 7, 0, 11]
    finally:
        os.close(fd)


def test_watches_overlap_and_an_unwatched_range_tells_nobody():
    table = Table()
    first, second = table.watch(0x1000, 10), table.watch(0x1005, 10)
    table.answer(bytes.fromhex("06 1007 0001"))
    assert table.take_change(first, 10) is not None
    assert table.take_change(second, 10) is not None
    table.unwatch(first)
    table.answer(bytes.fromhex("06 1001 0001"))
    assert table.take_change(second, 10) is None
    table.answer(bytes.fromhex("06 1001 0002"))
    assert table.take_change(second, 10) is None


def test_watches_are_bounded():
    table = Table()
    with pytest.raises(TableError, match="beyond the table"):
        table.watch(0xFFFF, 2)
    ids = [table.watch(0, 1) for _ in range(WATCHES)]
    assert len(set(ids)) == len(ids)
    with pytest.raises(TableError, match="no room for another watch"):
        table.watch(0, 1)
    table.unwatch(ids[0])
    assert table.watch(0, 1) == ids[0]


def test_fc7_flags_are_set_one_at_a_time():
    table = Table()
    table.set_flags(scenario_error=True)
    table.set_flags(line_down=True)
    assert table.answer(bytes.fromhex("07")) == bytes.fromhex("07 03")
    table.set_flags(line_down=False)
    assert table.answer(bytes.fromhex("07")) == bytes.fromhex("07 02")


# --- written since start: what a write scenario may send ---

def test_a_fresh_table_has_nothing_written(table):
    assert table.unwritten(0, 1) == 0
    assert table.unwritten(0x7FFF, 2) == 0x7FFF
    with pytest.raises(TableError):
        table.unwritten(0xFFFF, 2)


@pytest.mark.parametrize("request_hex, written", [
    ("05 0025 ff00", [2]),                       # bit 37: register 2, whatever else it holds
    ("05 0025 0000", [2]),                       # a coil switched off is data too
    ("06 0014 0000", [20]),                      # zero, the value the table held
    ("0f 001f 0002 01 00", [1, 2]),              # bits 31, 32: registers 1 and 2
    ("10 0014 0002 04 0000 0000", [20, 21]),
    ("17 0000 0001 0014 0002 04 0000 0000", [20, 21]),   # FC 23: its write part only
])
def test_every_modbus_write_marks_its_registers_written_whatever_the_value(
        table, request_hex, written):
    table.answer(H(request_hex))
    for register in range(0, 24):
        assert (table.unwritten(register, 1) is None) == (register in written), register


def test_a_broadcast_write_marks_written_and_a_refused_write_does_not(table):
    table.answer(H("06 0014 0007"), broadcast=True)
    assert table.unwritten(20, 1) is None
    assert ask(table, "10 7fff 0002 04 0000 0000") == "90 02"     # into the configuration zone
    assert table.unwritten(0x7FFF, 1) == 0x7FFF
    assert ask(table, "10 0030 0002 03 0000 00") == "90 03"       # byte count wrong
    assert table.unwritten(0x30, 2) == 0x30


def test_operator_writes_bit_writes_and_the_configuration_zone_mark_written(table):
    table.write(100, [0, 0])
    table.write_bits(16 * 200 + 3, b"\x00", 1)
    table.set_config(0x8000, [1, 2, 3])
    assert table.unwritten(100, 2) is None
    assert table.unwritten(200, 1) is None
    assert table.unwritten(0x8000, 3) is None
    assert table.unwritten(99, 4) == 99 and table.unwritten(100, 3) == 102
    assert table.unwritten(0x8000, 4) == 0x8003


def test_a_first_write_of_the_same_value_tells_a_first_writes_watch_only():
    table = Table()
    plain = table.watch(10, 2)
    first = table.watch(10, 2, first_writes=True)
    table.write(10, [0])                                   # the value the table held
    assert table.take_change(plain, 2) is None
    assert table.take_change(first, 2) == [0, 0]
    table.write(10, [0])                                   # written before: no change
    assert table.take_change(first, 2) is None
    table.answer(H("06 000b 0000"))                        # register 11's first write
    assert table.take_change(first, 2) == [0, 0]
    table.write(11, [5])
    assert table.take_change(plain, 2) == [0, 5] and table.take_change(first, 2) == [0, 5]
