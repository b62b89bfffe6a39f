"""The Modbus firewall (issue 17): [[rule]] tables select plain clients by CIDR (IPv4 and
IPv6); units, functions, registers and read-only say what they may do; the first rule that
selects a client decides, [firewall] default the others.  A refused request gets exception
0x01 and never reaches the line (the scripted serial slave's record is the wire) nor the
table.  Peers: tests/peers/fault_slave.py on the pty (holding register i holds 1000 + i,
FC 6 echoed), raw sockets."""
import json
import socket
import struct
import subprocess
import sys

import pytest

from tests.integration.ops.test_reload import reload
from tests.modbus import mbap
from tests.ops import status, wait_for_log

pytestmark = pytest.mark.integration

REPLY_S = 3.0
RULES = """
[firewall]
default = "deny"

[[rule]]                    # 1: the IPv6 loopback reads only
client = "::1"
read-only = true

[[rule]]                    # 2: IPv4 loopback: unit 1, FC 3 and 6, registers 0-9
client = "127.0.0.0/8"
units = "1"
functions = [3, 6]
registers = "0-9"

[[rule]]                    # 3: never decides for 127.0.0.1: rule 2 selects it first
client = "127.0.0.1"
"""


def read(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 3, address, count)


def write(address: int, value: int) -> bytes:
    return struct.pack(">BHH", 6, address, value)


def connect(host: str, port: int) -> socket.socket:
    sock = socket.create_connection((host, port), timeout=REPLY_S)
    return sock


def ask(sock: socket.socket, tid: int, unit: int, pdu: bytes) -> bytes:
    sock.sendall(mbap(tid, unit, pdu))
    head = b""
    while len(head) < 7:
        chunk = sock.recv(7 - len(head))
        assert chunk, "connection closed"
        head += chunk
    got_tid, _, length, got_unit = struct.unpack(">HHHB", head)
    assert (got_tid, got_unit) == (tid, unit)
    body = b""
    while len(body) < length - 1:
        body += sock.recv(length - 1 - len(body))
    return body


def seen_by_slave(record) -> list[bytes]:
    """The PDUs the serial slave received (address and CRC off)."""
    return [bytes.fromhex(line.split(" ", 2)[2])[1:-2]
            for line in record.read_text().splitlines() if line.split(" ", 2)[1] == "rx"]


@pytest.fixture
def gateway(tmp_path, pty_pair, recording_peer, start_gateway):
    """gateway(rules, *options) -> (gw, the serial slave's record, the file)."""
    def start(rules: str, *options: str):
        record = recording_peer("fault_slave.py")
        path = tmp_path / "mbgw.toml"
        path.write_text('[serial]\nbaudrate = 19200\n' + rules)
        gw = start_gateway(pty_pair.gateway, "--config", str(path), *options)
        return gw, record, path
    return start


def test_a_cidr_rule_limits_units_functions_and_registers_and_the_line_never_sees_the_rest(
        gateway):
    gw, record, _ = gateway(RULES)
    with connect("127.0.0.1", gw.port) as sock:
        refused = [(2, read(0, 2)),            # unit 2: not in units
                   (1, bytes.fromhex("04 0000 0001")),   # FC 4: not in functions
                   (1, read(8, 5)),            # registers 8..12: past 9
                   (1, write(10, 7))]          # register 10
        for tid, (unit, pdu) in enumerate(refused, 1):
            assert ask(sock, tid, unit, pdu) == bytes((pdu[0] | 0x80, 0x01))
        assert ask(sock, 10, 1, read(8, 2)) == bytes.fromhex("03 04 03f0 03f1")
        assert ask(sock, 11, 1, write(9, 7)) == write(9, 7)
    assert seen_by_slave(record) == [read(8, 2), write(9, 7)]
    firewall = status(gw)["firewall"]
    assert [r["refused"] for r in firewall["rules"]] == [0, 4, 0]
    assert firewall["refused"] == 4 and firewall["default"] == "deny"
    text = subprocess.run([sys.executable, "-m", "mbgw", "status", "--control", gw.control],
                          capture_output=True, text=True, check=True).stdout
    assert "firewall   3 rules, default deny: 4 requests refused" in text
    log = gw.log()
    assert "firewall: refused client 127.0.0.1:" in log and "unit 2 function 3" in log
    assert log.count("firewall: refused") == 1          # once a minute per client


def test_an_ipv6_client_is_selected_by_its_cidr_and_read_only_refuses_writes(gateway):
    gw, record, _ = gateway(RULES, "--bind", "::1")
    with connect("::1", gw.port) as sock:
        assert ask(sock, 1, 1, write(100, 7)) == bytes.fromhex("86 01")
        assert ask(sock, 2, 1, read(100, 1)) == bytes.fromhex("03 02 044c")
    assert seen_by_slave(record) == [read(100, 1)]
    assert [r["refused"] for r in status(gw)["firewall"]["rules"]] == [1, 0, 0]


def test_default_deny_refuses_a_client_no_rule_selects_table_included(gateway):
    gw, record, _ = gateway('[firewall]\ndefault = "deny"\n[[rule]]\nclient = "10.0.0.0/8"\n',
                            "--table")
    with connect("127.0.0.1", gw.port) as sock:
        assert ask(sock, 1, 1, read(0, 1)) == bytes.fromhex("83 01")
        assert ask(sock, 2, 250, write(0, 7)) == bytes.fromhex("86 01")    # the table's unit
        s = status(gw)
    assert seen_by_slave(record) == []
    assert s["firewall"]["refused_default"] == 2
    assert s["clients"][0]["firewall_refused"] == 2


def test_read_only_keeps_the_table_unwritten(gateway):
    gw, _, _ = gateway('[[rule]]\nclient = "127.0.0.1"\nread-only = true\n', "--table")
    with connect("127.0.0.1", gw.port) as sock:
        assert ask(sock, 1, 250, write(0, 7)) == bytes.fromhex("86 01")
        assert ask(sock, 2, 250, read(0, 1)) == bytes.fromhex("03 02 0000")


def test_a_reload_applies_new_rules_to_the_open_connection(gateway):
    gw, record, path = gateway("")
    assert "firewall" not in status(gw)
    with connect("127.0.0.1", gw.port) as sock:
        assert ask(sock, 1, 1, write(1, 5)) == write(1, 5)
        path.write_text(path.read_text() + '[[rule]]\nclient = "127.0.0.1"\nread-only = true\n')
        reload(gw, "firewall: 1 rule, default allow")
        assert ask(sock, 2, 1, write(1, 6)) == bytes.fromhex("86 01")
        assert ask(sock, 3, 1, read(1, 1)) == bytes.fromhex("03 02 03e9")
    assert seen_by_slave(record) == [write(1, 5), read(1, 1)]


def test_the_table_server_of_master_mode_applies_the_rules(tmp_path, start_master):
    path = tmp_path / "mbgw.toml"
    path.write_text('[serial]\nmode = "master"\n[[rule]]\nclient = "127.0.0.1"\n'
                    'units = "1"\nread-only = true\n')
    port = socket.create_server(("127.0.0.1", 0))
    table_port = port.getsockname()[1]
    port.close()
    gw = start_master("--config", str(path), "--table", "--table-address", "9",
                      "--table-port", str(table_port))
    with connect("127.0.0.1", table_port) as sock:
        assert ask(sock, 1, 1, write(0, 7)) == bytes.fromhex("86 01")
        assert ask(sock, 2, 2, read(0, 1)) == bytes.fromhex("83 01")
        assert ask(sock, 3, 1, read(0, 1)) == bytes.fromhex("03 02 0000")
    wait_for_log(gw, "firewall: refused client 127.0.0.1:")
    out = subprocess.run([sys.executable, "-m", "mbgw", "status", "--json", "--control",
                          gw.control], capture_output=True, text=True, check=True).stdout
    assert json.loads(out)["firewall"]["rules"][0]["refused"] == 2
