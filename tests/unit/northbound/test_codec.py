"""Registers to published values and values to write PDUs (issue 28's types): the byte and
word orders, strings, two's complement."""
import struct

import pytest

from mbgw.config.scenario import TYPE_REGISTERS, parse_scenario
from mbgw.northbound import codec


def scenario(quantity=1, function=3, **keys):
    return parse_scenario({"name": "v", "slave": 5, "function": function, "address": 100,
                           "quantity": quantity, "table": 0, "cycle": 1000, **keys}, "s")


# 0x41200000 is 10.0 as an IEEE 754 single: ABCD 4120 0000
@pytest.mark.parametrize("swap, registers", [
    ("none", [0x4120, 0x0000]), ("words", [0x0000, 0x4120]), ("bytes", [0x2041, 0x0000])])
def test_float32_in_each_order(swap, registers):
    sc = scenario(2, type="float32", swap=swap)
    assert codec.decode(sc, registers) == [10.0]
    pdu = codec.encode(sc, "v", 10.0)
    assert pdu == struct.pack(">BHHB2H", 16, 100, 2, 4, *registers)


@pytest.mark.parametrize("kind, registers, value", [
    ("int16", [0xFFFE], -2), ("uint16", [0xFFFE], 0xFFFE),
    ("int32", [0xFFFF, 0xFFFD], -3), ("uint32", [0x0001, 0x0002], 0x10002),
    ("bool", [0x0100], True), ("bool", [0], False)])
def test_numbers_and_bools(kind, registers, value):
    sc = scenario(len(registers), type=kind)
    assert codec.decode(sc, registers) == [value]
    assert codec.decode(sc, list(struct.unpack(f">{len(registers)}H",
                                               codec.encode(sc, "v", value)[-2 * len(registers):]
                                               ))) == [value]


def test_string_two_characters_a_register_high_byte_first_trailing_nuls_dropped():
    sc = scenario(3, type="string")
    assert codec.decode(sc, [0x4142, 0x4300, 0x0000]) == ["ABC"]
    assert codec.encode(sc, "v", "ABC") == struct.pack(">BHHB3H", 16, 100, 3, 6, 0x4142,
                                                       0x4300, 0)
    with pytest.raises(codec.WriteRefused, match="at most 6 characters"):
        codec.encode(sc, "v", "ABCDEFG")


def test_untyped_registers_are_one_metric_each_and_bits_are_coils():
    sc = scenario(3)
    assert codec.element_names(sc) == ["v/0", "v/1", "v/2"]
    assert codec.decode(sc, [1, 2, 3]) == [1, 2, 3]
    assert codec.encode(sc, "v/2", 7) == struct.pack(">BHH", 6, 102, 7)
    bits = scenario(2, function=1)
    assert codec.decode(bits, [1, 0]) == [True, False]
    assert codec.encode(bits, "v/1", True) == struct.pack(">BHH", 5, 101, 0xFF00)


@pytest.mark.parametrize("kind, value", [("int16", 40000), ("uint16", -1), ("uint16", 1.5),
                                         ("float32", "x"), ("bool", 2), ("uint32", True)])
def test_a_value_the_type_cannot_carry_is_refused(kind, value):
    sc = scenario(TYPE_REGISTERS[kind], type=kind)
    with pytest.raises(codec.WriteRefused):
        codec.encode(sc, "v", value)
