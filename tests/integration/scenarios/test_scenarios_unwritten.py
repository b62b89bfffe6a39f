"""Write scenarios send only data somebody gave (issue 22, point 5): a cyclic FC 16 on a fresh
table waits ("waiting for data") until a client has written every register it sends, then
sends exactly those values; `send-unwritten = true` sends the table's zeros at once; registers
restored from the table file count as written.

The wire is pymodbus's RTU server's own record of the requests it decoded
(tests/peers/pymodbus_slave.py --record), and what its registers hold afterwards; holding
register n holds 100 + n until written."""
import struct

import pytest

from mbgw.table.persist import FIRST, encode
from tests.integration.scenarios.test_scenarios_serial import (
    TABLE_UNIT,
    WAIT_S,
    poll,
    wait_for_scenario,
    write_config,
)
from tests.integration.slave.test_faults import received
from tests.modbus import read_holding
from tests.ops import mbgw, status
from tests.wait import until

pytestmark = pytest.mark.integration

SLAVE = 1
SETPOINT = {"name": "setpoint", "slave": SLAVE, "function": 16, "address": 20, "quantity": 2,
            "table": 20, "cycle": 200}
TICK = poll("tick", SLAVE, 3, 0, 1, 100, cycle=200)       # a read beside it: its runs count time


@pytest.fixture
def line(tmp_path, pty_pair, start_peer, start_gateway):
    """line(scenarios, **table) -> (gateway, the record of pymodbus's requests)."""
    def start(scenarios: list[dict], **table):
        record = tmp_path / "wire.txt"
        start_peer("pymodbus_slave.py", pty_pair.device, str(SLAVE), "--silent-unknown",
                   "--record", str(record))
        path = tmp_path / "mbgw.toml"
        write_config(path, scenarios, **table)
        return start_gateway(pty_pair.gateway, "--config", str(path)), record
    return start


def writes(record) -> list[bytes]:
    """The FC 16 requests the slave received (address and PDU)."""
    return [frame for _, frame in received(record) if frame[1] == 16]


def fc16(*values: int) -> bytes:
    return bytes((SLAVE,)) + struct.pack(f">BHHB{len(values)}H", 16, 20, len(values),
                                         2 * len(values), *values)


def test_a_fresh_cyclic_write_sends_nothing_until_a_client_writes_then_exactly_that(
        line, client):
    gw, record = line([SETPOINT, TICK])
    s = wait_for_scenario(gw, "setpoint", lambda sc: sc["message"].startswith("waiting"),
                          "waiting for data")
    assert (s["state"], s["runs"], s["message"]) == \
        ("starting", 0, "waiting for data: table register 20 not written since start")
    shown = mbgw("scenarios", "--control", gw.control)
    assert "waiting for data: table register 20" in shown.stdout, shown.stdout
    # its cycle has come six times (as the read's), and the line carried no write
    wait_for_scenario(gw, "tick", lambda sc: sc["runs"] >= s["runs"] + 6, "five cycles")
    assert writes(record) == []
    c = client(gw)
    assert c.ask(TABLE_UNIT, bytes.fromhex("06 0014 002a"))[0] == 0x06      # table 20 = 42
    wait_for_scenario(gw, "setpoint", lambda sc: "register 21" in sc["message"],
                      "waiting for register 21")
    assert c.ask(TABLE_UNIT, bytes.fromhex("06 0015 0000"))[0] == 0x06      # 21 = 0: given
    until(lambda: writes(record), "the write", WAIT_S)
    assert c.ask(SLAVE, read_holding(20, 2)) == bytes.fromhex("03 04 002a 0000")
    assert set(writes(record)) == {fc16(42, 0)}
    s = status(gw)["scenarios"][0]
    assert (s["name"], s["state"], s["message"]) == ("setpoint", "running", "")


def test_send_unwritten_sends_the_tables_zeros_from_the_start(line, client):
    gw, record = line([{**SETPOINT, "send-unwritten": True}])
    until(lambda: writes(record), "the write", WAIT_S)
    assert writes(record)[0] == fc16(0, 0)
    assert client(gw).ask(SLAVE, read_holding(20, 2)) == bytes.fromhex("03 04 0000 0000")


def test_registers_restored_from_the_table_file_count_as_written(state_directory, line, client):
    """The table file holds 0x0800-0x7FFF: 7 and 0 at 0x0800 (the 0 written once, as data)."""
    saved = state_directory / "table.bin"
    registers = [0] * (0x8000 - FIRST)
    registers[0] = 7
    saved.write_bytes(encode(registers))
    gw, record = line([{**SETPOINT, "table": 0x0800}], persist=str(saved))
    until(lambda: writes(record), "the write", WAIT_S)
    assert writes(record)[0] == fc16(7, 0)
    s = wait_for_scenario(gw, "setpoint", lambda sc: sc["runs"] >= 1, "run")
    assert s["message"] == "" and s["state"] == "running", s
