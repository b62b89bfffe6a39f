"""TLS to upstream servers (issue 17): master mode's `tls` slaveid ranges, `tls` TCP
scenarios and `tls = true` server routes (issue 24; a serial face's, the TCP face's) reach
pymodbus's TLS server (tests/peers/pymodbus_tcp_servers.py --tls), which requires mbgw's
client certificate; certificates made by openssl (tests/pki.py)."""
import os

import pytest

from mbgw.config.model import UpstreamTlsConfig
from mbgw.scenarios.tcp_runner import TLS_REFUSED, TcpRunner
from tests.harness import Peer, free_port
from tests.integration.master.rig import (
    ask,
    holding_reply,
    identity,
    read_holding,
    status,
    wait_for_log,
)
from tests.integration.master.test_serial_faces import lines_file
from tests.integration.scenarios.test_scenarios_tcp import (
    CONDITION_S,
    FREE,
    READ_3,
    TABLE_UNIT,
    TCPTO_MS,
    Scenario,
    StandInEngine,
    read_table,
    registers,
    scenario_status,
    scenario_toml,
)
from tests.pki import Authority
from tests.wait import until

pytestmark = pytest.mark.integration

TLS_HOST = "127.0.8.1"
PLAIN_HOST = "127.0.7.1"
PATH_UNAVAILABLE = 0x0A


@pytest.fixture
def pki(tmp_path):
    """(our CA, another CA, mbgw's client certificate and key from our CA)."""
    ca = Authority(tmp_path)
    return ca, Authority(tmp_path, "other"), ca.issue("mbgw")


@pytest.fixture
def tls_servers():
    """tls_servers(authority, client_ca, *hosts, names=None) -> port: pymodbus TLS servers
    with a server certificate from authority for names (its subjectAltName; by default the
    hosts' addresses), requiring a client certificate from client_ca."""
    started: list[Peer] = []

    def start(authority: Authority, client_ca: Authority, *hosts: str,
              names: str | None = None) -> int:
        port = free_port()
        cert, key = authority.issue(f"server{len(started)}", server=True,
                                    names=names or ", ".join(f"IP:{h}" for h in hosts))
        started.append(Peer("pymodbus_tcp_servers.py", str(port), *hosts, "--tls", str(cert),
                            str(key), str(client_ca.cert)))
        return port
    yield start
    for peer in started:
        peer.stop()


def client_options(ca: Authority, client) -> list[str]:
    cert, key = client
    return ["--tls-client-cert", str(cert), "--tls-client-key", str(key),
            "--tls-server-ca", str(ca.cert)]


def test_a_tls_range_is_answered_over_tls_beside_a_plain_range(
        pki, tls_servers, servers_at, start_master, line):
    ca, _, client = pki
    tls_port = tls_servers(ca, ca, TLS_HOST)
    plain_port, _ = servers_at(PLAIN_HOST)
    gw = start_master("--slaveid", f"1 4 1 0 {TLS_HOST} tls", "--slaveid",
                      f"5 5 1 0 {PLAIN_HOST}", "--mdbport", str(plain_port),
                      "--tls-server-port", str(tls_port), *client_options(ca, client))
    for address, host, unit in ((1, TLS_HOST, 1), (3, TLS_HOST, 3), (5, PLAIN_HOST, 1),
                                (3, TLS_HOST, 3)):
        ask(line, read_holding(address), expected=holding_reply(address, *identity(host, unit)))
    connections = {c["server"]: c for c in status(gw)["upstream"]["connections"]}
    assert connections[f"{TLS_HOST}:{tls_port}"]["tls"] is True
    assert connections[f"{TLS_HOST}:{tls_port}"]["requests"] == 3
    assert connections[f"{PLAIN_HOST}:{plain_port}"]["tls"] is False
    assert [r["tls"] for r in status(gw)["slaveid"]] == [True, False]


def test_a_server_whose_certificate_is_from_another_ca_is_refused(
        pki, tls_servers, start_master, line):
    ca, other, client = pki
    tls_port = tls_servers(other, ca, TLS_HOST)
    gw = start_master("--slaveid", f"1 4 1 0 {TLS_HOST} tls", "--exception",
                      "--tls-server-port", str(tls_port), *client_options(ca, client))
    for _ in range(2):
        ask(line, read_holding(1), expected=bytes((1, 0x83, PATH_UNAVAILABLE)))
    log = wait_for_log(gw, "TLS handshake failed")
    assert log.count("TLS handshake failed") == 1          # once until reachable again
    assert "TLS handshake failed: the server's certificate: unable to get local issuer " \
           "certificate" in log
    assert status(gw)["counters"]["unreachable"] == 2


@pytest.fixture
def tls_runner(pki):
    ca, _, (cert, key) = pki
    engine = StandInEngine()
    run = TcpRunner(engine, TCPTO_MS, tls=UpstreamTlsConfig(
        client_cert=str(cert), client_key=str(key), server_ca=str(ca.cert)))
    run.start()
    yield run
    run.stop()
    run.join()
    os.close(engine.wake_fd)


def test_a_tcp_scenario_over_tls(pki, tls_servers, tls_runner):
    ca, other, _ = pki
    port = tls_servers(ca, ca, TLS_HOST)
    tls_runner.engine.queue(Scenario(f"{TLS_HOST}:{port}", unit=7, tls=True))
    assert tls_runner.engine.result() == (registers(8, 1, 7), None, 0)
    impostor = tls_servers(other, ca, "127.0.8.2")
    tls_runner.engine.queue(Scenario(f"127.0.8.2:{impostor}", tls=True))
    assert tls_runner.engine.result() == (None, TLS_REFUSED, 0)
    tls_runner.engine.queue(Scenario(f"{TLS_HOST}:{port}", unit=3, tls=True), READ_3)
    assert tls_runner.engine.result() == (registers(8, 1, 3), None, 0)


@pytest.fixture
def slave_with(tmp_path, pty_pair, start_gateway):
    """slave_with(file text, serial=more [serial] lines) -> gateway: `mbgw slave` with the
    table, from a file."""
    def start(text: str, serial: str = ""):
        path = tmp_path / "mbgw.toml"
        path.write_text(f'[serial]\nbaudrate = 19200\n{serial}\n[net]\ntcpto = {TCPTO_MS}\n\n'
                        f'[table]\nenabled = true\n\n' + text)
        return start_gateway(pty_pair.gateway, "--config", str(path))
    return start


def test_slave_mode_runs_tls_scenarios_from_the_file(pki, tls_servers, slave_with):
    ca, other, (cert, key) = pki
    port = tls_servers(ca, ca, TLS_HOST)
    impostor = tls_servers(other, ca, "127.0.8.2")
    keys = dict(function=3, address=0, quantity=3, cycle=100, tls=True)
    gw = slave_with(
        scenario_toml("secure", f"{TLS_HOST}:{port}", unit=5, table=FREE, **keys)
        + scenario_toml("impostor", f"127.0.8.2:{impostor}", table=FREE + 8, **keys)
        + f'\n[tls]\nclient-cert = "{cert}"\nclient-key = "{key}"\nserver-ca = "{ca.cert}"\n',
        serial="down-after = 0\n")     # the impostor keeps its own message, never "server down"
    until(lambda: read_table(gw.port, TABLE_UNIT, FREE, 3) == [8, 1, 5],
          "the data in the table", CONDITION_S)
    secure = until(lambda: (s := scenario_status(gw, "secure"))["successes"] and s,
                   "a success", CONDITION_S)
    assert secure["state"] == "running" and secure["target"].endswith("unit 5 TLS")
    refused = until(lambda: (s := scenario_status(gw, "impostor"))["state"] == "error" and s,
                    "the impostor's error", CONDITION_S)
    assert refused["message"] == "connection refused: TLS handshake failed"
    assert read_table(gw.port, TABLE_UNIT, FREE + 8, 3) == [0, 0, 0]


def fingerprint(authority: Authority, name: str) -> str:
    """The SHA-256 fingerprint of a certificate tls_servers made, as openssl prints it."""
    import subprocess
    done = subprocess.run(["openssl", "x509", "-noout", "-fingerprint", "-sha256", "-in",
                           str(authority.dir / f"{name}.pem")], capture_output=True, text=True,
                          check=True)
    return done.stdout.strip().split("=", 1)[1]


def test_a_server_whose_certificate_is_for_another_address_is_refused_unless_pinned(
        pki, tls_servers, start_master, line):
    """Any certificate from the CA could impersonate any server: the address dialled must be
    in its subjectAltName (IP or DNS), or its fingerprint pinned on the range."""
    ca, _, client = pki
    port = tls_servers(ca, ca, TLS_HOST, "127.0.8.3", names="IP:127.0.8.9, DNS:elsewhere")
    pinned = fingerprint(ca, "server0")
    gw = start_master("--slaveid", f"1 1 1 0 {TLS_HOST} tls", "--slaveid",
                      f"2 2 1 0 127.0.8.3 tls {pinned}", "--exception",
                      "--tls-server-port", str(port), *client_options(ca, client))
    ask(line, read_holding(1), expected=bytes((1, 0x83, PATH_UNAVAILABLE)))
    log = wait_for_log(gw, f"server {TLS_HOST}:{port} unreachable: the server's certificate is "
                           f"not for {TLS_HOST}")
    ask(line, read_holding(2), expected=holding_reply(2, *identity("127.0.8.3", 1)))
    assert status(gw)["counters"]["unreachable"] == 1, log


def test_a_pinned_fingerprint_that_does_not_match_is_refused(pki, tls_servers, start_master,
                                                             line):
    ca, _, client = pki
    port = tls_servers(ca, ca, TLS_HOST)
    wrong = ":".join(["AB"] * 32)
    gw = start_master("--slaveid", f"1 1 1 0 {TLS_HOST} tls {wrong}", "--exception",
                      "--tls-server-port", str(port), *client_options(ca, client))
    ask(line, read_holding(1), expected=bytes((1, 0x83, PATH_UNAVAILABLE)))
    wait_for_log(gw, "the server's certificate is not the one pinned")


def test_a_tcp_scenario_checks_the_name_or_the_pin(pki, tls_servers, tls_runner):
    ca, _, _ = pki
    port = tls_servers(ca, ca, "127.0.0.1", names="DNS:localhost")
    tls_runner.engine.queue(Scenario(f"127.0.0.1:{port}", unit=7, tls=True))
    assert tls_runner.engine.result() == (None, TLS_REFUSED, 0)
    tls_runner.engine.queue(Scenario(f"localhost:{port}", unit=7, tls=True))
    assert tls_runner.engine.result() == (registers(0, 1, 7), None, 0)


def test_a_serial_face_reaches_a_route_server_over_tls(
        tmp_path, pki, tls_servers, start_master, line):
    """A `[[route]]` of a serial face with `server` and `tls = true` is reached over TLS on
    the route's port, as a `tls` slaveid range is: mbgw's client certificate, the server's
    checked against server-ca or the route's pinned fingerprint."""
    ca, _, client = pki
    port = tls_servers(ca, ca, TLS_HOST, "127.0.8.3", names=f"IP:{TLS_HOST}")
    pinned = fingerprint(ca, "server0")
    config = lines_file(tmp_path / "routes.toml", [], [
        {"units": [1], "from": "serial", "server": [TLS_HOST, port], "tls": True},
        {"units": [2], "from": "serial", "server": ["127.0.8.3", port], "tls": True,
         "fingerprint": pinned},
        {"units": [3], "from": "serial", "server": ["127.0.8.3", port], "tls": True,
         "address": 4}])
    gw = start_master("--config", str(config), "--exception", *client_options(ca, client))
    ask(line, read_holding(1), expected=holding_reply(1, *identity(TLS_HOST, 1)))
    ask(line, read_holding(2), expected=holding_reply(2, *identity("127.0.8.3", 2)))
    # the pin is the server's, whichever route reaches it
    ask(line, read_holding(3), expected=holding_reply(3, *identity("127.0.8.3", 4)))
    connections = {c["server"]: c for c in status(gw)["upstream"]["connections"]}
    assert connections[f"{TLS_HOST}:{port}"]["tls"] is True
    assert connections[f"127.0.8.3:{port}"]["tls"] is True


def test_a_tcp_face_reaches_a_route_server_over_tls(
        tmp_path, pki, tls_servers, start_gateway, pty_pair, client):
    """The Modbus TCP face's `tls = true` server routes (slave/servers.py) choose TLS as a
    serial face's do: unit 9 over TLS answers; a server from another CA is 0x0A."""
    ca, other, certificate = pki
    port = tls_servers(ca, ca, TLS_HOST)
    impostor = tls_servers(other, ca, "127.0.8.2")
    config = lines_file(tmp_path / "routes.toml", [], [
        {"units": [9], "server": [TLS_HOST, port], "tls": True, "address": 1},
        {"units": [10], "server": ["127.0.8.2", impostor], "tls": True, "address": 1}])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--exception",
                       *client_options(ca, certificate))
    c = client(gw)
    assert c.ask(9, read_holding(1)[1:]) == holding_reply(1, *identity(TLS_HOST, 1))[1:]
    assert c.ask(10, read_holding(1)[1:]) == bytes((0x83, PATH_UNAVAILABLE))
    wait_for_log(gw, "TLS handshake failed")
