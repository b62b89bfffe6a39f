"""`[general] gateway-unit` on every face (issue 29): the gateway answers its identity
functions (FC 43/14, 17, 8) as that unit id on a Modbus TCP face and as that serial address
on a serial face, any other function 0x01, whether the table is on or not.

Peers that are not ours: pymodbus's TCP client against a master-mode daemon's TCP face,
pymodbus's RTU serial master on line serial of that daemon and on a slave-mode daemon's line
in master mode, and a recording pymodbus RTU slave (the meter, which the gateway unit's
requests never reach)."""
import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

import mbgw
from tests.integration.lines.test_lines import METER_UNIT, received
from tests.integration.lines.test_lines_of_both_modes import (
    BAUD,
    meters,  # noqa: F401 (the fixture)
    meters_line,
)
from tests.integration.master.test_serial_faces import lines_file
from tests.modbus import REPLY_S

pytestmark = pytest.mark.integration

GATEWAY_UNIT = 200
TCP_ROUTE = {"units": list(range(32, 64)), "line": "meters", "offset": -31}


def identifies_the_gateway(client, unit: int = GATEWAY_UNIT) -> None:
    """The gateway's identity as pymodbus reads it, and 0x01 for anything else."""
    objects = client.read_device_information(read_code=1, object_id=0, device_id=unit)
    assert not objects.isError(), objects
    assert objects.conformity == 0x83
    assert objects.information == {0: b"mbgw", 1: b"mbgw", 2: mbgw.__version__.encode()}
    server_id = client.report_device_id(device_id=unit)
    assert not server_id.isError(), server_id
    assert server_id.identifier.startswith(b"mbgw\xff")
    echo = client.diag_query_data(b"\x5a\xa5", device_id=unit)
    assert not echo.isError() and echo.message == b"\x5a\xa5"
    refused = client.read_holding_registers(0, count=1, device_id=unit)
    assert refused.isError() and refused.exception_code == 0x01


def serial_master(device: str) -> ModbusSerialClient:
    client = ModbusSerialClient(device, baudrate=BAUD, timeout=REPLY_S, retries=0)
    assert client.connect()
    return client


def test_a_master_mode_daemon_answers_on_its_tcp_face_and_line_serial(
        tmp_path, start_gateway, pty_pair, meters):  # noqa: F811
    config = lines_file(tmp_path / "lines.toml", [meters_line(meters)], [TCP_ROUTE])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", str(BAUD),
                       "--gateway-unit", str(GATEWAY_UNIT), mode="master")   # no table
    with ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0) as tcp:
        identifies_the_gateway(tcp)
        got = tcp.read_holding_registers(0, count=1, device_id=METER_UNIT)   # the route
        assert not got.isError() and got.registers == [100]
    line = serial_master(pty_pair.device)
    try:
        identifies_the_gateway(line)
    finally:
        line.close()
    assert len(received(meters.record)) == 1          # the gateway unit never reached it


def test_a_slave_mode_daemons_line_in_master_mode_answers(tmp_path, start_gateway, pty_pair,
                                                           second_pty, start_peer):
    start_peer("pymodbus_slave.py", pty_pair.device, "1", "--silent-unknown")
    panel = {"name": "panel", "device": second_pty.gateway, "mode": "master",
             "baudrate": BAUD}
    config = lines_file(tmp_path / "lines.toml", [panel], [])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", str(BAUD),
                       "--gateway-unit", str(GATEWAY_UNIT))
    line = serial_master(second_pty.device)
    try:
        identifies_the_gateway(line)
        # an address no route of the panel takes stays unanswered: another slave's
        with pytest.raises(ModbusIOException):
            line.read_device_information(device_id=GATEWAY_UNIT - 1)
    finally:
        line.close()
    with ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0) as tcp:
        identifies_the_gateway(tcp)
