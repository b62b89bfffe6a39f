"""The configuration zone (mbgw.table.identity) against its layout in mbgw.toml(5), THE
CONFIGURATION ZONE: expected registers written here by hand from that page."""
import pytest

import mbgw
from mbgw.config.model import LineFormat, MasterConfig, SerialConfig, SlaveConfig, TableConfig
from mbgw.config.slaveid import SlaveIdTable
from mbgw.table import identity
from mbgw.table.memory import Table, TableError

VENDOR = [0x6D62, 0x6777] + [0] * 14                  # "mb" "gw"
PRODUCT = [0x6D62, 0x6777, 0x204D, 0x6F64, 0x6275,    # "mb" "gw" " M" "od" "bu"
           0x7320, 0x6761, 0x7465, 0x7761, 0x7900]    # "s " "ga" "te" "wa" "y\0"
PRODUCT += [0] * 6


def version_registers() -> list[int]:
    text = mbgw.__version__.encode().ljust(16, b"\0")
    return [text[i] * 256 + text[i + 1] for i in range(0, 16, 2)]


def zone_of(table: Table) -> list[int]:
    return table.read(0x8000, 0x44)


def test_slave_mode_defaults():
    settings = SlaveConfig(serial=SerialConfig("/dev/ttyX"))
    table = Table()
    identity.fill(table, settings, "slave")
    units = [0] * 16
    units[15] = 0x7F80                    # units 247-254: bits 7-14 of 0x8033 + 15
    assert zone_of(table) == [
        *VENDOR, *PRODUCT, *version_registers(),
        1,                                # 0x8028 slave
        0x0000, 0x2580,                   # 9600
        8, ord("N"), 1,                   # 8n1
        0,                                # rtu
        0x0081, 0x80FE,                   # functions 1-7, 15, 16, 23
        0,                                # no table address in slave mode
        1,                                # direct messaging on
        *units,
        0,                                # no table port in slave mode
    ]
    assert table.read(0x8044, 15) == UNKNOWN_LOCATION
    assert table.read(0x8053, 4) == [0] * 4
    assert table.read(0xFFFF) == [0]


UNKNOWN_LOCATION = [0x556E, 0x6B6E, 0x6F77, 0x6E20, 0x6C6F, 0x6361, 0x7469, 0x6F6E] + [0] * 7


def test_location_fills_0x8044_with_its_30_characters():
    """The guide's set location, 30 bytes max, in mbgw.toml(5)'s 0x8044-0x8052."""
    text = b"Pump house 3, hall B, bay 12!!"
    settings = SlaveConfig(serial=SerialConfig("/dev/ttyX"), location=text.decode())
    table = Table()
    identity.fill(table, settings, "slave")
    assert table.read(0x8044, 15) == [text[i] << 8 | text[i + 1] for i in range(0, 30, 2)]
    assert table.read(0x8053) == [0]


def test_master_mode_settings():
    settings = MasterConfig(
        serial=SerialConfig("/dev/ttyX", baudrate=115200, format=LineFormat(7, "e", 2),
                            protocol="ascii"),
        slaveid=SlaveIdTable(),
        table=TableConfig(enabled=True, units=(1, 17, 255), functions=(3, 16, 23),
                          address=5, port=1502))
    table = Table()
    identity.fill(table, settings, "master")
    zone = zone_of(table)
    assert zone[:0x28] == [*VENDOR, *PRODUCT, *version_registers()]
    assert zone[0x28:0x33] == [
        2,                                # master
        0x0001, 0xC200,                   # 115200 = 0x0001C200
        7, ord("E"), 2,
        1,                                # ascii
        0x0081, 0x0008,                   # bits 23, 16 | 3: 0x00810008
        5,                                # the table address
        0,                                # direct: slave mode only
    ]
    assert zone[0x33:0x43] == [0x0002, 0x0002] + [0] * 13 + [0x8000]   # units 1, 17, 255
    assert zone[0x43] == 1502


@pytest.mark.parametrize("parity, code", [("n", 0x4E), ("e", 0x45), ("o", 0x4F),
                                          ("m", 0x4D), ("s", 0x53)])
def test_parity_codes(parity, code):
    settings = SlaveConfig(serial=SerialConfig("/dev/ttyX", format=LineFormat(8, parity, 1)))
    assert identity.zone(settings, "slave")[0x2C] == code


def test_the_zone_is_read_only_to_modbus_and_the_operator():
    table = Table()
    identity.fill(table, SlaveConfig(serial=SerialConfig("/dev/ttyX")), "slave")
    assert table.answer(bytes.fromhex("03 80 00 00 02")) == bytes.fromhex("03 04 6d 62 67 77")
    assert table.answer(bytes.fromhex("06 80 00 00 00")) == bytes.fromhex("86 02")
    with pytest.raises(TableError):
        table.write(0x8000, [0])
    assert table.read(0x8000, 2) == [0x6D62, 0x6777]


def test_long_text_is_cut_to_its_registers():
    assert identity.ascii_registers("abcdef", 2) == [0x6162, 0x6364]
    assert identity.ascii_registers("a", 2) == [0x6100, 0]
