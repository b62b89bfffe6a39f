"""The gateway's identity on the wire (issue 29): FC 43/14, FC 17 and FC 8 answered by the
table on every unit that reaches it and by `--gateway-unit`, read by pymodbus's TCP client
against a running `mbgw slave`.  Expected values from the issue and the Modbus Application
Protocol V1.1b3 (6.8, 6.13, 6.21): vendor and product "mbgw", the version of `mbgw
--version`, the host name as object 6, server id "mbgw" with run indicator 0xFF."""
import os
import socket

import pytest
from pymodbus.client import ModbusTcpClient

import mbgw
from tests.harness import read_pty
from tests.integration.ops.test_reload import config_set, reload
from tests.integration.table import test_table_master, test_table_slave
from tests.modbus import read_holding
from tests.modbus import rtu_frame as rtu
from tests.ops import wait_for

pytestmark = pytest.mark.integration
table_gateway = test_table_slave.table_gateway      # the fixtures, shared
pymodbus_client = test_table_slave.pymodbus_client
table_master = test_table_master.table_master
servers = test_table_master.servers
TABLE_ADDRESS = test_table_master.TABLE

GATEWAY_UNIT = 200


@pytest.mark.parametrize("unit", [247, 254])
def test_the_table_identifies_the_gateway(table_gateway, pymodbus_client, unit):
    c = pymodbus_client(table_gateway())
    rr = c.read_device_information(read_code=2, object_id=0, device_id=unit)
    assert not rr.isError(), rr
    assert rr.conformity == 0x83
    assert rr.information[0] == b"mbgw" and rr.information[1] == b"mbgw"
    assert rr.information[2] == mbgw.__version__.encode()
    assert rr.information[6] == socket.gethostname().encode()
    sid = c.report_device_id(device_id=unit)
    assert not sid.isError(), sid
    # server id, run indicator on, the version; pymodbus takes the last byte counted for
    # the run indicator (it expects no additional data), so the version lacks its last one
    assert sid.identifier == (b"mbgw\xff" + mbgw.__version__.encode())[:-1]


def test_fc8_counts_the_requests_to_the_table_and_clears(table_gateway, pymodbus_client):
    c = pymodbus_client(table_gateway())
    assert not c.diag_clear_counters(device_id=250).isError()
    for _ in range(5):
        assert not c.read_holding_registers(0, count=1, device_id=251).isError()
    assert c.write_register(0x8000, 1, device_id=251).isError()   # 0x02: read-only zone
    echo = c.diag_query_data(b"\xa5\x37", device_id=250)
    assert not echo.isError() and echo.message == b"\xa5\x37"
    # since the clear: 5 reads, 1 exception, the echo, this one
    assert c.diag_read_bus_message_count(device_id=252).message == 8
    assert c.diag_read_bus_exception_error_count(device_id=252).message == 1
    assert c.diag_read_device_message_count(device_id=252).message == 10
    assert not c.diag_clear_counters(device_id=250).isError()
    assert c.diag_read_bus_message_count(device_id=252).message == 1


def test_the_gateway_unit_answers_identity_functions_only(table_gateway, pymodbus_client):
    gw = table_gateway("--gateway-unit", str(GATEWAY_UNIT))
    c = pymodbus_client(gw)
    rr = c.read_device_information(read_code=1, object_id=0, device_id=GATEWAY_UNIT)
    assert not rr.isError(), rr
    assert rr.information[0] == b"mbgw"
    assert c.report_device_id(device_id=GATEWAY_UNIT).identifier.startswith(b"mbgw\xff")
    refused = c.read_holding_registers(0, count=1, device_id=GATEWAY_UNIT)
    assert refused.isError() and refused.exception_code == 0x01
    # the gateway unit and the table count together
    assert c.diag_read_bus_exception_error_count(device_id=GATEWAY_UNIT).message == 1


def test_the_gateway_unit_answers_with_the_table_off(pty_pair, start_peer, start_gateway,
                                                     pymodbus_client):
    start_peer("pymodbus_slave.py", pty_pair.device, "1", "--silent-unknown")
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--gateway-unit",
                       str(GATEWAY_UNIT))
    c = pymodbus_client(gw)
    rr = c.read_device_information(read_code=4, object_id=0, device_id=GATEWAY_UNIT)
    assert not rr.isError(), rr
    assert rr.information[0] == b"mbgw"


def test_master_mode_answers_the_identity_on_the_tables_serial_address_and_port(
        table_master, serial_client):
    gw, port = table_master()
    serial = serial_client()
    rr = serial.read_device_information(read_code=1, object_id=0, device_id=TABLE_ADDRESS)
    assert not rr.isError(), rr
    assert rr.conformity == 0x83
    assert rr.information == {0: b"mbgw", 1: b"mbgw", 2: mbgw.__version__.encode()}
    assert serial.diag_query_data(b"\x12\x34", device_id=TABLE_ADDRESS).message == b"\x12\x34"
    tcp = ModbusTcpClient("127.0.0.1", port=port, timeout=3.0, retries=0)
    assert tcp.connect()
    try:
        model = tcp.read_device_information(read_code=4, object_id=5, device_id=1)
        assert model.information == {5: b"master"}
        # the serial side's two requests, the TCP side's two: one table, one count
        assert tcp.diag_read_bus_message_count(device_id=1).message == 4
    finally:
        tcp.close()


def test_a_reload_gives_and_takes_the_gateway_unit(reloadable):
    path, gw, c = reloadable(1)
    report_server_id = bytes.fromhex("11")
    assert c.ask(GATEWAY_UNIT, report_server_id) == bytes.fromhex("91 0b")   # the line's
    config_set(path, "general", "gateway-unit", str(GATEWAY_UNIT))
    reload(gw, "configuration reloaded")
    assert c.ask(GATEWAY_UNIT, report_server_id)[:7] == bytes.fromhex("11 0a") + b"mbgw\xff"
    assert c.ask(GATEWAY_UNIT, read_holding(0, 1)) == bytes.fromhex("83 01")
    assert c.ask(1, read_holding(0, 1)) == bytes.fromhex("03 02 0064")    # the line still
    config_set(path, "general", "gateway-unit", "0")
    reload(gw, "configuration reloaded", count=2)
    assert c.ask(GATEWAY_UNIT, report_server_id) == bytes.fromhex("91 0b")


def test_fc8_counts_a_bad_crc_to_the_tables_serial_address(table_master, line):
    gw, _ = table_master()
    bad = rtu(bytes((TABLE_ADDRESS,)) + read_holding(0x1000, 1))
    os.write(line, bad[:-1] + bytes((bad[-1] ^ 0xFF,)))
    wait_for(gw, lambda s: s["table"]["serial"]["crc_errors"] == 1, "counted the bad CRC")
    # 12 bus communication error count: the bad CRC; 11 bus message count: it, the request
    # for 12 and this one
    for sub, count in ((0x0C, 1), (0x0B, 3)):
        request = bytes((TABLE_ADDRESS, 0x08, 0x00, sub, 0x00, 0x00))
        os.write(line, rtu(request))
        expected = rtu(bytes((TABLE_ADDRESS, 0x08, 0x00, sub, 0x00, count)))
        assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
