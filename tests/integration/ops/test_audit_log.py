"""Audit events end to end with `--log-format json`: a real gateway (slave mode over a socat
pty, tests/peers/fault_slave.py on the line), real clients (pymodbus plain and TLS, a plain
socket, the web console over HTTP, `mbgw clients close`/`stats reset`, SIGHUP), and the
gateway's stderr read back as one JSON object a line.  Each record names its event by its
MESSAGE_ID, and its fields name the client (with the port it connected from), the user, the
unit, the function, the rule and the reason; what the client saw is checked on the wire.
The same records as journald stores them (`journalctl -o json`) are checked under systemd
itself by scripts/container-test.sh: this host's PID 1 is not systemd."""
import json
import os
import signal
import socket

import pytest
from pymodbus.client import ModbusTcpClient

from mbgw.audit import Kind
from tests.harness import free_port
from tests.integration.scenarios.test_scenarios_serial import write_config
from tests.integration.tls.test_tls import client_context, read, tls_client, tls_options
from tests.integration.web.test_web_api import Web, listen_on, set_passwords
from tests.ops import mbgw, status, wait_for_log
from tests.pki import Authority

pytestmark = pytest.mark.integration

REPLY_S = 3.0
RULES = """
[firewall]
default = "deny"

[[rule]]                    # 1: unit 1 reads only
client = "127.0.0.0/8"
units = "1"
read-only = true
"""


def records(gw) -> list[dict]:
    """Every line the gateway wrote, each a JSON object."""
    return [json.loads(line) for line in gw.log().splitlines()]


def events(gw, kind: Kind) -> list[dict]:
    return [r for r in records(gw) if r.get("MESSAGE_ID") == kind.message_id]


@pytest.fixture
def gateway(tmp_path, pty_pair, recording_peer, start_gateway):
    def start(config: str, *options: str):
        recording_peer("fault_slave.py")
        path = tmp_path / "mbgw.toml"
        path.write_text('[serial]\nbaudrate = 19200\n' + config)
        return start_gateway(pty_pair.gateway, "--config", str(path), "--log-format", "json",
                             *options)
    return start


def test_a_firewall_refusal_of_a_pymodbus_client_is_a_json_record_with_its_id(gateway):
    gw = gateway(RULES)
    c = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0)
    assert c.connect()
    try:
        assert c.read_holding_registers(0, count=2, device_id=1).registers == [1000, 1001]
        assert c.write_register(5, 7, device_id=1).exception_code == 1      # on the wire
        local_port = c.socket.getsockname()[1]
    finally:
        c.close()
    wait_for_log(gw, '"MBGW_EVENT": "firewall-refused"')
    (refused,) = events(gw, Kind.FIREWALL_REFUSED)
    assert refused["MESSAGE"].startswith(
        f"mbgw.firewall: firewall: refused client 127.0.0.1:{local_port} (role none) unit 1 "
        f"function 6")
    assert refused["PRIORITY"] == "4" and refused["SYSLOG_IDENTIFIER"] == "mbgw"
    assert (refused["MBGW_CLIENT"], refused["MBGW_UNIT"], refused["MBGW_FUNCTION"],
            refused["MBGW_RULE"]) == (f"127.0.0.1:{local_port}", "1", "6", "1")
    assert "MBGW_ROLE" not in refused
    assert any(r["MESSAGE"].startswith("mbgw: ") and "MESSAGE_ID" not in r
               for r in records(gw))                    # the other lines: JSON as well


def test_a_client_authip_refuses_is_a_connection_refused_record(gateway):
    gw = gateway("[net]\nauthip = [\"192.0.2.7\"]\n")
    with socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_S) as sock:
        assert sock.recv(1) == b""                      # closed before a byte is read
    wait_for_log(gw, '"MBGW_EVENT": "connection-refused"')
    (refused,) = events(gw, Kind.CONNECTION_REFUSED)
    assert (refused["MBGW_CLIENT"], refused["MBGW_REASON"]) == ("127.0.0.1", "not in authip")
    assert refused["MESSAGE"].startswith("mbgw.tcp: connection from 127.0.0.1 refused")


def test_the_operators_actions_and_a_reload_are_records_that_name_who(gateway):
    gw = gateway("")
    with socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_S) as sock:
        local = f"127.0.0.1:{sock.getsockname()[1]}"
        (client,) = [c for c in status(gw)["clients"] if c["peer"] == local]
        assert mbgw("clients", "close", str(client["id"]), "--control",
                    gw.control).returncode == 0
        assert sock.recv(1) == b""                      # closed on the wire
    assert mbgw("stats", "reset", "--control", gw.control).returncode == 0
    wait_for_log(gw, '"MBGW_EVENT": "counters-reset"')
    (closed,) = events(gw, Kind.CLIENT_CLOSED)
    assert (closed["MBGW_CLIENT"], closed["MBGW_USER"]) == (local, f"uid {os.getuid()}")
    (reset,) = events(gw, Kind.COUNTERS_RESET)
    assert reset["MBGW_USER"] == f"uid {os.getuid()}" and reset["PRIORITY"] == "6"

    path = gw.args[gw.args.index("--config") + 1]
    with open(path, "a") as file:
        file.write("[net]\nexception = true\n")
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, '"MBGW_EVENT": "config-changed"')
    (changed,) = events(gw, Kind.CONFIG_CHANGED)
    assert (changed["MBGW_SOURCE"], changed["MBGW_KEYS"]) == ("sighup", "exception")
    assert changed["MESSAGE"] == "mbgw: configuration reloaded: exception changed"


def test_web_logins_and_a_change_from_the_console_are_records_with_the_user(
        tmp_path, pty_pair, recording_peer, start_gateway):
    recording_peer("fault_slave.py")
    path = tmp_path / "mbgw.toml"
    write_config(path, [], baudrate=19200)
    set_passwords(path, ("admin", "admin-secret-1"))
    web = Web(f"http://127.0.0.1:{listen_on(path)}")
    gw = start_gateway(pty_pair.gateway, "--config", str(path), "--log-format", "json")
    assert web.login("admin", "wrong") == 401
    assert web.login("admin", "admin-secret-1") == 200
    assert web.ok("POST", "/api/config", {"group": "serial", "key": "stout", "value": 700})
    wait_for_log(gw, '"MBGW_SOURCE": "sighup"')         # the console's change, applied
    (failed,) = events(gw, Kind.LOGIN_FAILED)
    assert (failed["MBGW_CLIENT"], failed["MBGW_USER"], failed["MBGW_REASON"],
            failed["PRIORITY"]) == ("127.0.0.1", "admin", "wrong user or password", "4")
    (ok,) = events(gw, Kind.LOGIN_OK)
    assert (ok["MBGW_CLIENT"], ok["MBGW_USER"], ok["PRIORITY"]) == ("127.0.0.1", "admin", "6")
    by_web, by_reload = events(gw, Kind.CONFIG_CHANGED)
    assert (by_web["MBGW_SOURCE"], by_web["MBGW_USER"], by_web["MBGW_KEYS"]) == \
        ("web", "web admin@127.0.0.1", "serial.stout")
    assert by_reload["MBGW_SOURCE"] == "sighup" and "stout" in by_reload["MBGW_KEYS"]


def test_a_tls_client_without_a_certificate_is_a_tls_refused_record(gateway, tmp_path):
    ca = Authority(tmp_path)
    port = free_port()
    gw = gateway("", *tls_options(ca, ca.issue("server", server=True), port))
    client = tls_client(port, client_context(ca))       # pymodbus, no client certificate
    try:
        assert read(client) is None
    finally:
        client.close()
    wait_for_log(gw, '"MBGW_EVENT": "tls-refused"')
    (refused,) = events(gw, Kind.TLS_REFUSED)
    assert refused["MBGW_CLIENT"] == "127.0.0.1"
    assert refused["MBGW_REASON"] == "TLS handshake refused (PEER_DID_NOT_RETURN_A_CERTIFICATE)"
    assert refused["MESSAGE"].startswith("mbgw.tcp: connection from 127.0.0.1 refused: ")
