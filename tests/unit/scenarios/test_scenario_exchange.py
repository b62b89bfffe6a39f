"""A scenario's request and reply (mbgw.scenarios.exchange) for every function, against PDUs
written here from the Modbus Application Protocol V1.1b3 (section 6 examples where it has
them), with a real exchange table; every wrong reply gets VPGate's message."""
import pytest

from mbgw.config.scenario import parse_scenario
from mbgw.scenarios import exchange
from mbgw.table.memory import Table

H = bytes.fromhex


@pytest.fixture
def table():
    return Table()


def scenario(function, **keys):
    base = {"name": "s", "slave": 1, "function": function, "cycle": 1000}
    if function == 23:
        base.update({"read-address": 3, "read-quantity": 6, "read-table": 10,
                     "write-address": 14, "write-quantity": 3, "write-table": 20})
    base.update(keys)
    return parse_scenario(base, "s")


def test_fc1_spec_example_into_register_bits(table):
    # read coils 20-38: request 01 00 13 00 13, reply 01 03 CD 6B 05 (section 6.1)
    sc = scenario(1, address=19, quantity=19, table="1.3")
    assert exchange.request_pdu(sc, table) == H("01 00 13 00 13")
    table.write(1, [0x0007])                   # bits 0-2 of register 1 are not the scenario's
    assert exchange.apply_reply(sc, table, H("01 03 cd 6b 05")).ok
    # CD 6B 05 LSB first from bit 1.3: register 1 bits 3-15 = 1,0,1,1,0,0,1,1,1,1,0,1,0
    assert table.read(1, 2) == [0x5E6F, 0x002B]


def test_fc2_spec_example(table):
    sc = scenario(2, address=196, quantity=22, table=0)
    assert exchange.request_pdu(sc, table) == H("02 00 c4 00 16")
    result = exchange.apply_reply(sc, table, H("02 03 ac db 35"))
    assert result.ok and result.data[:8] == [0, 0, 1, 1, 0, 1, 0, 1]
    assert table.read(0, 2) == [0xDBAC, 0x0035]


def test_fc3_spec_example(table):
    sc = scenario(3, address=107, quantity=3, table=50)
    assert exchange.request_pdu(sc, table) == H("03 00 6b 00 03")
    assert exchange.apply_reply(sc, table, H("03 06 02 2b 00 00 00 64")).ok
    assert table.read(50, 3) == [0x022B, 0, 0x64]


def test_fc4_spec_example(table):
    sc = scenario(4, address=8, quantity=1, table=7)
    assert exchange.request_pdu(sc, table) == H("04 00 08 00 01")
    assert exchange.apply_reply(sc, table, H("04 02 00 0a")).ok
    assert table.read(7) == [10]


def test_fc5_from_a_table_bit(table):
    sc = scenario(5, address=172, table="3.4")
    assert exchange.request_pdu(sc, table) == H("05 00 ac 00 00")
    table.write(3, [0x0010])
    pdu = exchange.request_pdu(sc, table)
    assert pdu == H("05 00 ac ff 00")          # the spec's example
    assert exchange.apply_reply(sc, table, H("05 00 ac ff 00"), pdu).ok
    assert exchange.apply_reply(sc, table, H("05 00 ac 00 00"), pdu).kind == \
        exchange.UNEXPECTED_DATA


def test_fc6_spec_example(table):
    sc = scenario(6, address=1, table=9)
    table.write(9, [3])
    pdu = exchange.request_pdu(sc, table)
    assert pdu == H("06 00 01 00 03")
    assert exchange.apply_reply(sc, table, H("06 00 01 00 03"), pdu).ok


def test_fc15_spec_example(table):
    # write coils 20-29 = CD 01 (section 6.11)
    sc = scenario(15, address=19, quantity=10, table=32)     # bits 32.. = register 2
    table.write(2, [0x01CD])
    pdu = exchange.request_pdu(sc, table)
    assert pdu == H("0f 00 13 00 0a 02 cd 01")
    assert exchange.apply_reply(sc, table, H("0f 00 13 00 0a"), pdu).ok
    assert exchange.apply_reply(sc, table, H("0f 00 13 00 09"), pdu).kind == \
        exchange.UNEXPECTED_DATA


def test_fc16_spec_example(table):
    sc = scenario(16, address=1, quantity=2, table=100)
    table.write(100, [0x000A, 0x0102])
    pdu = exchange.request_pdu(sc, table)
    assert pdu == H("10 00 01 00 02 04 00 0a 01 02")
    assert exchange.apply_reply(sc, table, H("10 00 01 00 02"), pdu).ok


def test_fc23_spec_example(table):
    # read 6 from 4 (address 3), write 3 to 15 (address 14): section 6.17
    sc = scenario(23)
    table.write(20, [0x00FF, 0x00FF, 0x00FF])
    pdu = exchange.request_pdu(sc, table)
    assert pdu == H("17 00 03 00 06 00 0e 00 03 06 00 ff 00 ff 00 ff")
    reply = H("17 0c 00 fe 0a cd 00 01 00 03 00 0d 00 ff")
    assert exchange.apply_reply(sc, table, reply, pdu).ok
    assert table.read(10, 6) == [0xFE, 0x0ACD, 1, 3, 0x0D, 0xFF]


@pytest.mark.parametrize("reply, kind, message", [
    ("83 01", "illegal-function", "received illegal function from slave (0x01)"),
    ("83 02", "illegal-address", "received illegal data address from slave (0x02)"),
    ("83 03", "illegal-value", "received illegal data value from slave (0x03)"),
    ("83 04", "device-failure", "slave failed to execute request (0x04)"),
    ("83 06", "busy", "slave is busy, cannot execute request (0x06)"),
    ("83 0a", "path-unavailable", "gateway path unavailable (0x0A)"),
    ("83 0b", "target-failed", "gateway target failed to respond (0x0B)"),
    ("83 05", "exception", "received exception 0x05 from slave"),
    ("04 04 00 01 00 02", "unexpected-function", "received unexpected function in answer"),
    ("84 02", "unexpected-function", "received unexpected function in answer"),
    ("03 02 00 01", "unexpected-data", "received unexpected data/quantity in answer"),
    ("03 04 00 01 00", "unexpected-data", "received unexpected data/quantity in answer"),
    ("", "unexpected-function", "received unexpected function in answer"),
])
def test_wrong_replies_leave_the_table_alone(table, reply, kind, message):
    sc = scenario(3, address=0, quantity=2, table=0)
    table.write(0, [7, 8])
    result = exchange.apply_reply(sc, table, H(reply))
    assert (result.kind, result.message()) == (kind, message)
    assert table.read(0, 2) == [7, 8]


def test_tcp_messages_say_server():
    assert exchange.error_message("timeout", tcp=True) == \
        "timeout, no answer from server after retrying"
    assert exchange.error_message("connection-lost", tcp=True) == "TCP connection lost"


def test_write_bits_keeps_the_other_bits_and_tells_watchers(table):
    import os
    fd = os.eventfd(0, os.EFD_NONBLOCK)
    watch = table.watch(3, 1, fd)
    table.write(3, [0xF00F])
    table.take_change(watch, 1)
    table.write_bits(3 * 16 + 4, b"\x05", 4)          # bits 4..7 of register 3 = 1,0,1,0
    assert table.read(3) == [0xF05F]
    assert table.take_change(watch, 1) == [0xF05F]
    table.write_bits(3 * 16 + 4, b"\x05", 4)          # the same: no change
    assert table.take_change(watch, 1) is None
    os.close(fd)
