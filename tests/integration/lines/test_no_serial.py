"""`[serial]` left out (issue 26): a slave-mode file whose `[[line]]` tables define the lines.
Line serial does not run, the Modbus TCP face has a thread of its own, and only the file's
`[[route]]`s reach the lines.

Peers that are not ours: pymodbus's Modbus TCP server behind a modbus-tcp line
(tests/peers/pymodbus_tcp_servers.py), pymodbus's RTU slave on a socat pty behind a serial
line, pymodbus's TCP client in front.
"""
import os
import signal

import pytest
from pymodbus.client import ModbusTcpClient

from tests.harness import free_port
from tests.integration.lines.test_lines import lines  # noqa: F401 (a fixture)
from tests.integration.web.test_web_api import (
    ADMIN_PASSWORD,
    USER_PASSWORD,
    Web,
    admin,
    listen_on,
    set_passwords,
)
from tests.ops import mbgw, metric_value, scraped, status, wait_for_log

pytestmark = pytest.mark.integration

INVERTER_UNITS = "1-10"       # to line inverter, unchanged
METERS_UNITS = "11-20"        # to line meters, offset -10: unit 15 is the slave at 5
METER = 5


def no_serial_toml(inverter: str, meters: str, routes: bool = True) -> str:
    """Line inverter (modbus-tcp) and line meters (a serial port), no [serial]."""
    text = ["[web]", "",
            "[[line]]", 'name = "inverter"', f'connect = "modbus-tcp://{inverter}"',
            "stout = 500",
            "[[line]]", 'name = "meters"', f'device = "{meters}"', "baudrate = 19200",
            "stout = 500"]
    if routes:
        text += ["[[route]]", f'units = "{INVERTER_UNITS}"', 'line = "inverter"',
                 "[[route]]", f'units = "{METERS_UNITS}"', 'line = "meters"', "offset = -10"]
    return "\n".join(text) + "\n"


@pytest.fixture
def setup(tmp_path, lines, start_peer):  # noqa: F811 (this module's own)
    """(the file, the meters line): a pymodbus TCP server at 127.0.0.1 and a pymodbus RTU
    slave at METER on a pty, the file naming both."""
    port = free_port()
    start_peer("pymodbus_tcp_servers.py", str(port), "127.0.0.1")
    meters = lines("meters", METER)
    path = tmp_path / "mbgw.toml"
    path.write_text(no_serial_toml(f"127.0.0.1:{port}", meters.pair.gateway))
    return path, meters


def test_check_config_takes_the_file_and_refuses_it_without_routes(setup, tmp_path):
    path, meters = setup
    done = mbgw("check-config", str(path))
    assert (done.returncode, done.stderr) == (0, "")
    bare = tmp_path / "bare.toml"
    bare.write_text(no_serial_toml("127.0.0.1:502", meters.pair.gateway, routes=False))
    done = mbgw("check-config", str(bare))
    assert done.returncode == 78
    assert "serial.device: missing, so line serial does not run and no unit reaches a line" \
        in done.stderr
    assert "[[route]]" in done.stderr


def test_a_tcp_client_reads_both_lines_through_the_gateway(setup, start_gateway):
    path, _ = setup
    set_passwords(path, ("admin", ADMIN_PASSWORD), ("user", USER_PASSWORD))
    web_port = listen_on(path)
    metrics_port = free_port()
    gw = start_gateway(None, "--config", str(path), "--exception",
                       "--metrics", f"127.0.0.1:{metrics_port}")
    client = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=5)
    assert client.connect()
    try:
        # pymodbus_tcp_servers: host 127.0.0.1's registers 0 -> 0, 1 -> 1, 2 -> the unit
        inverter = client.read_holding_registers(0, count=3, device_id=7)
        assert inverter.registers == [0, 1, 7]
        # pymodbus_slave: holding register n holds 100 + n
        meter = client.read_holding_registers(2, count=2, device_id=10 + METER)
        assert meter.registers == [102, 103]
        unrouted = client.read_holding_registers(0, count=1, device_id=30)
        assert unrouted.isError() and unrouted.exception_code == 0x0A
    finally:
        client.close()
    s = status(gw)
    assert "serial" not in s
    rows = {r["name"]: r for r in s["lines"]}
    assert sorted(rows) == ["inverter", "meters"]
    assert (rows["inverter"]["replies"], rows["meters"]["replies"]) == (1, 1)
    text = mbgw("status", "--control", gw.control).stdout
    assert "inverter" in text and "meters" in text and "serial  " not in text
    families = scraped(metrics_port)
    assert {x.labels["line"] for x in families["mbgw_line_up"].samples} == \
        {"inverter", "meters"}
    assert metric_value(families, "mbgw_line_up", line="meters") == 1
    assert metric_value(families, "mbgw_replies", "mbgw_replies_total",
                        line="inverter") == 1
    web = admin(Web(f"http://127.0.0.1:{web_port}"))   # the console's Lines page reads this
    assert [r["name"] for r in web.ok("GET", "/api/status")["lines"]] == ["inverter", "meters"]
    assert "internal error" not in gw.log()
    assert "no [serial]: lines inverter, meters" in gw.log()


def test_serial_added_by_a_reload_takes_a_restart(setup, start_gateway, pty):
    path, _ = setup
    gw = start_gateway(None, "--config", str(path))
    path.write_text(f'[serial]\ndevice = "{pty}"\n' + path.read_text())
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "serial: [serial] added or left out takes effect at restart")
    assert [r["name"] for r in status(gw)["lines"]] == ["inverter", "meters"]
    client = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=5)
    assert client.connect()
    try:        # the routes in force still reach the lines
        assert client.read_holding_registers(2, count=1, device_id=10 + METER).registers \
            == [102]
    finally:
        client.close()
