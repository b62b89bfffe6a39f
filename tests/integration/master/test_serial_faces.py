"""Lines in master mode as serial faces routed to targets (issue 24): a serial master on a
socat pty polls serial addresses; each route takes its addresses to a remote Modbus TCP server
(pymodbus's, tests/peers/pymodbus_tcp_servers.py) at a unit rewritten by an offset or to one
fixed address, or to the exchange table; an address no route takes is never answered.  Two
lines in master mode in one daemon each reach their own server.

The lines and routes reach `mbgw master` through its configuration file; the masters
are raw RTU frames checked byte for byte against frames built here (tests/modbus.py's CRC),
mbpoll and pymodbus's serial client.  "No answer" is checked by order: a request that must be
answered follows the one that must not, and the first bytes back must be its answer."""
import json
import os
import struct
import subprocess
from pathlib import Path

import pytest
from pymodbus.client import ModbusSerialClient

from tests.harness import free_port, read_pty
from tests.integration.master.test_master import BAUD, REPLY_S, holding_reply, identity
from tests.modbus import rtu_frame as rtu

pytestmark = pytest.mark.integration

METER = "127.0.4.1"          # on the servers' common port
PANEL_METER = "127.0.4.2"    # on the common port too: line panel's
OTHER_PORT_METER = "127.0.4.3"   # alone on a port of its own
TABLE_ADDRESS = 10
FREE = 0x1000                # a free zone of the table


def read(address: int, start: int = 0, count: int = 3) -> bytes:
    return struct.pack(">BBHH", address, 0x03, start, count)


def write_multiple(address: int, start: int, *values: int) -> bytes:
    return struct.pack(f">BBHHB{len(values)}H", address, 0x10, start, len(values),
                       2 * len(values), *values)


def ask(fd: int, request: bytes, expected: bytes) -> None:
    """Write the request (ADU without CRC); the first frame back must be `expected`."""
    os.write(fd, rtu(request))
    want = rtu(expected)
    got = read_pty(fd, len(want) + 1)
    assert got == want, f"{request.hex(' ')}: got {got.hex(' ')!r}, expected {want.hex(' ')!r}"


def unanswered(fd: int, request: bytes, then: bytes, expected: bytes) -> None:
    """request gets no answer: `then`, written right behind it, is answered first."""
    os.write(fd, rtu(request) + rtu(then))
    want = rtu(expected)
    got = read_pty(fd, len(want) + 1)
    assert got == want, f"{request.hex(' ')} then {then.hex(' ')}: got {got.hex(' ')!r}"


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    return json.dumps(str(value))


def lines_file(path: Path, lines, routes) -> Path:
    """A configuration file with these [[line]] and [[route]] tables (dicts of their keys;
    a route's units a list, its server [HOST, PORT])."""
    text = []
    for line in lines:
        text.append("[[line]]")
        text += [f"{key} = {_toml_value(value)}" for key, value in line.items()]
    for route in routes:
        text.append("[[route]]")
        for key, value in route.items():
            if key == "units":
                value = ",".join(str(unit) for unit in value)
            elif key == "server":
                value = f"{value[0]}:{value[1]}"
            text.append(f"{key} = {_toml_value(value)}")
    path.write_text("\n".join(text) + "\n")
    return path


@pytest.fixture
def lines_master(pty_pair, start_gateway, tmp_path):
    """lines_master(*options, lines=[], routes=[]) -> `mbgw master` on pty_pair at BAUD with
    these [[line]] and [[route]] tables in its configuration file."""
    def start(*options: str, lines=(), routes=()):
        config = lines_file(tmp_path / "lines.toml", lines, routes)
        return start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", BAUD,
                             *options, mode="master", listen=False)
    return start


@pytest.fixture
def meters(servers_at):
    """(the common port, the other port): METER and PANEL_METER on one, OTHER_PORT_METER on
    the other."""
    port, _ = servers_at(METER, PANEL_METER)
    other, _ = servers_at(OTHER_PORT_METER)
    return port, other


def test_routes_reach_servers_with_offset_and_address_and_the_table(
        lines_master, meters, pty_pair, open_line):
    port, other = meters
    lines_master(
        "--mdbport", str(port), "--slaveid", f"40 40 1 0 {METER}", "--table",
        "--table-address", str(TABLE_ADDRESS), "--table-port", str(free_port()),
        routes=[{"units": [1, 2, 3, 4], "from": "serial", "server": [METER, port], "offset": 10},
                {"units": [20, 21], "from": "serial", "server": [OTHER_PORT_METER, other],
                 "address": 7},
                {"units": [30, 31], "from": "serial", "table": True}])
    line = open_line(pty_pair.device)
    # offset: address 1 is unit 11 on METER, 4 is unit 14; the reply has the master's address
    ask(line, read(1), holding_reply(1, *identity(METER, 11)))
    ask(line, read(4), holding_reply(4, *identity(METER, 14)))
    # one fixed address, on the server's own port
    ask(line, read(20), holding_reply(20, *identity(OTHER_PORT_METER, 7)))
    ask(line, read(21), holding_reply(21, *identity(OTHER_PORT_METER, 7)))
    # the table: what address 30 writes, address 31 reads
    ask(line, write_multiple(30, FREE, 0x1234, 0xBEEF),
        struct.pack(">BBHH", 30, 0x10, FREE, 2))
    ask(line, read(31, FREE, 2), holding_reply(31, 0x1234, 0xBEEF))
    # a route to the table replaces table-address as line serial's way to it
    unanswered(line, read(TABLE_ADDRESS, FREE, 1), then=read(31, FREE, 1),
               expected=holding_reply(31, 0x1234))


def test_an_address_no_route_takes_is_never_answered(lines_master, meters, pty_pair,
                                                       open_line):
    port, _ = meters
    lines_master("--mdbport", str(port), "--slaveid", f"40 40 1 0 {METER}", "--exception",
                 "--table", "--table-address", str(TABLE_ADDRESS), "--table-port",
                 str(free_port()),
                 routes=[{"units": [1], "from": "serial", "server": [METER, port]}])
    line = open_line(pty_pair.device)
    expected = holding_reply(1, *identity(METER, 1))
    unanswered(line, read(5), then=read(1), expected=expected)
    # with routes of its own, the face no longer routes by the slaveid table...
    unanswered(line, read(40), then=read(1), expected=expected)
    # ...but table-address stays its route to the table (no route of its own goes there)
    ask(line, read(TABLE_ADDRESS, FREE, 1), holding_reply(TABLE_ADDRESS, 0))


def test_a_servers_unreachable_is_0x0a_and_the_master_keeps_its_address(lines_master, meters,
                                                                       pty_pair, open_line):
    port, _ = meters
    lines_master("--mdbport", str(port), "--slaveid", f"40 40 1 0 {METER}", "--exception",
                 routes=[{"units": [9], "from": "serial", "server": ["127.0.4.9", port],
                          "address": 1}])
    line = open_line(pty_pair.device)
    ask(line, read(9), bytes((9, 0x83, 0x0A)))


def test_two_lines_in_master_mode_each_reach_their_own_server(
        lines_master, meters, pty_pair, second_pty, open_line):
    port, _ = meters
    lines_master(
        "--mdbport", str(port), "--slaveid", f"1 1 1 0 {METER}",
        lines=[{"name": "panel", "device": second_pty.gateway, "baudrate": int(BAUD),
                "mode": "master"}],
        routes=[{"units": [1, 2], "from": "panel", "server": [PANEL_METER, port],
                 "offset": 4}])
    serial, panel = open_line(pty_pair.device), open_line(second_pty.device)
    # the same serial address on each line: line serial's slaveid table, panel's route
    ask(serial, read(1), holding_reply(1, *identity(METER, 1)))
    ask(panel, read(1), holding_reply(1, *identity(PANEL_METER, 5)))
    # both masters at once, each gets its own answer
    os.write(serial, rtu(read(1)))
    os.write(panel, rtu(read(2)))
    assert read_pty(serial, 11) == rtu(holding_reply(1, *identity(METER, 1)))
    assert read_pty(panel, 11) == rtu(holding_reply(2, *identity(PANEL_METER, 6)))
    # mbpoll on panel, pymodbus's serial client on serial
    out = subprocess.run(["mbpoll", "-m", "rtu", "-b", BAUD, "-P", "none", "-a", "2", "-0",
                          "-1", "-o", str(REPLY_S), "-t", "4", "-r", "0", "-c", "3",
                          second_pty.device], capture_output=True, text=True, timeout=10)
    assert out.returncode == 0, out.stdout + out.stderr
    assert [int(v) for v in _mbpoll_values(out.stdout)] == identity(PANEL_METER, 6)
    client = ModbusSerialClient(pty_pair.device, baudrate=int(BAUD), timeout=REPLY_S,
                                retries=0)
    assert client.connect()
    try:
        reply = client.read_holding_registers(0, count=3, device_id=1)
        assert not reply.isError() and reply.registers == identity(METER, 1)
    finally:
        client.close()


def _mbpoll_values(text: str) -> list[str]:
    """The values of mbpoll's "[reg]: value" lines."""
    return [line.split(":", 1)[1].strip() for line in text.splitlines()
            if line.startswith("[")]
