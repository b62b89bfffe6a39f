"""`mbgw config show --security [--json]`: the security settings a file puts in force.  The
file is made with `mbgw config set` and `mbgw config password`, the certificates by openssl
(tests/pki.py); the report must name the listeners with their limits, TLS as the daemon would
offer it, the firewall, the web console's users (never a hash), and whether other users can
read the file."""
import json
import os

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from tests.pki import Authority

RULES = """
[firewall]
default = "deny"

[[rule]]
client = "10.0.0.0/8"
units = "1-3"
functions = [3, 4]
read-only = true
"""


def mbgw(*args, stdin: str | None = None):
    result = CliRunner().invoke(main, [str(a) for a in args], input=stdin, prog_name="mbgw")
    return result


@pytest.fixture
def secured(tmp_path):
    """A slave-mode file with TLS, authip, a firewall rule and the web console on."""
    ca = Authority(tmp_path)
    cert, key = ca.issue("server", server=True)
    path = tmp_path / "mbgw.toml"
    for words in (("serial", "device", "/dev/ttyS9"), ("net", "authip", "1", "10.1.2.3"),
                  ("net", "max-connections-per-ip", "2"), ("net", "bind", "127.0.0.1"),
                  ("tls", "cert", cert), ("tls", "key", key), ("tls", "ca", ca.cert),
                  ("web", "listen", "127.0.0.1:8080")):
        if words[:2] == ("web", "listen"):
            assert mbgw("config", "password", "admin", "--stdin", "--config", path,
                        stdin="s3cret-pass\n").exit_code == 0
        result = mbgw("config", "set", *words, "--config", path)
        assert result.exit_code == 0, result.output
    path.write_text(path.read_text() + RULES)
    return path


def test_the_json_report_names_listeners_tls_firewall_web_and_file_access(secured):
    result = mbgw("config", "show", "--security", "--json", "--config", secured)
    assert result.exit_code == 0, result.output
    assert "scrypt" not in result.output and "s3cret" not in result.output
    report = json.loads(result.output)
    listeners = {li["name"]: li for li in report["listeners"]}
    assert listeners["modbus"] == {
        "name": "modbus", "address": "127.0.0.1", "port": 502, "transport": "plain",
        "max_connections": 5, "max_connections_per_ip": 2, "authip": ["10.1.2.3"]}
    assert listeners["modbus-tls"]["port"] == 802
    assert listeners["modbus-tls"]["transport"] == "tls"
    assert listeners["web"] == {"name": "web", "listen": "127.0.0.1:8080", "transport": "http"}
    tls = report["tls"]
    assert tls["versions"] == ["TLSv1.2", "TLSv1.3"] and "error" not in tls
    assert "TLS_AES_256_GCM_SHA384" in tls["suites"]                 # a TLS 1.3 suite
    assert any(s.startswith("ECDHE-ECDSA-") for s in tls["suites"])  # the EC certificate's
    assert tls["client_certificate"] == "required" and tls["crl"] is None
    assert report["firewall"] == {"default": "deny", "rules": [{
        "rule": 1, "selects": "rule 1 (client 10.0.0.0/8)", "units": [1, 2, 3],
        "functions": [3, 4], "registers": "all", "read_only": True}]}
    assert report["web"]["users"] == ["admin"] and report["web"]["https"] is False
    access = report["file"]
    assert access["others_can_read"] is False          # mbgw config password closed it
    assert access["owner"] and access["group"]


def test_the_text_report_says_when_other_users_can_read_the_file(secured):
    os.chmod(secured, 0o644)
    result = mbgw("config", "show", "--security", "--config", secured)
    assert result.exit_code == 0, result.output
    text = result.output
    assert "mode 0644: other users CAN read it" in text
    assert "modbus-tls tls    127.0.0.1 port 802" in text
    assert "versions TLSv1.2, TLSv1.3" in text
    assert "firewall   default deny, 1 rules" in text
    assert "web        127.0.0.1:8080 HTTP (no TLS); passwords set: admin" in text
    assert "scrypt" not in text


def test_a_file_whose_certificate_cannot_be_used_is_refused_naming_the_key(secured,
                                                                          tmp_path):
    bad = tmp_path / "garbage.pem"
    bad.write_text("not a certificate\n")
    text = secured.read_text()
    cert_line = next(line for line in text.splitlines() if line.startswith("cert ="))
    secured.write_text(text.replace(cert_line, f'cert = "{bad}"'))
    result = mbgw("config", "show", "--security", "--json", "--config", secured)
    assert result.exit_code == 1 and "tls.cert" in result.output and str(bad) in result.output


def test_json_needs_security():
    result = mbgw("config", "show", "--json", "--config", "/dev/null")
    assert result.exit_code == 2 and "--json goes with --security" in result.output


def test_master_mode_lists_the_tables_server_and_an_open_metrics_endpoint(tmp_path):
    path = tmp_path / "mbgw.toml"
    for words in (("serial", "mode", "master"), ("table", "enabled", "on"),
                  ("table", "port", "5020"), ("general", "metrics", "127.0.0.1:9502")):
        assert mbgw("config", "set", *words, "--config", path).exit_code == 0
    report = json.loads(mbgw("config", "show", "--security", "--json", "--config",
                             path).output)
    assert report["listeners"] == [
        {"name": "table", "address": "all addresses (IPv4 and IPv6)", "port": 5020,
         "transport": "plain", "max_connections": 32, "authip": "any client"},
        {"name": "metrics", "listen": "127.0.0.1:9502", "transport": "http",
         "authentication": "none"}]
    text = mbgw("config", "show", "--security", "--config", path).output
    assert "authip     (empty: any client may connect)" in text and "tls        off" in text


def test_transparent_mode_lists_the_tables_server_with_its_own_max_connections(tmp_path):
    path = tmp_path / "mbgw.toml"
    for words in (("serial", "mode", "transparent"), ("net", "bind", "127.0.0.1"),
                  ("table", "max-connections", "8")):
        assert mbgw("config", "set", *words, "--config", path).exit_code == 0
    report = json.loads(mbgw("config", "show", "--security", "--json", "--config",
                             path).output)
    assert report["listeners"][0] == {
        "name": "table", "address": "127.0.0.1", "port": 502, "transport": "plain",
        "max_connections": 8, "authip": "any client"}


def test_master_mode_lists_the_table_servers_bind_and_authip(tmp_path):
    path = tmp_path / "mbgw.toml"
    for words in (("serial", "mode", "master"), ("table", "enabled", "on"),
                  ("net", "bind", "127.0.0.1"), ("net", "authip", "1", "10.1.2.3")):
        result = mbgw("config", "set", *words, "--config", path)
        assert result.exit_code == 0, result.output
    report = json.loads(mbgw("config", "show", "--security", "--json", "--config",
                             path).output)
    assert report["listeners"][0] == {
        "name": "table", "address": "127.0.0.1", "port": 502, "transport": "plain",
        "max_connections": 32, "authip": ["10.1.2.3"]}
    assert mbgw("check-config", "--config", path).exit_code == 0
