"""The settings of TLS to upstream servers: the `tls` word of a slaveid range, a TCP
scenario's `tls`, the [tls] client keys and their checks (certificates made by openssl)."""
import hashlib
import ipaddress
import subprocess
import sys

import pytest
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding

from mbgw.config.model import MasterConfig, SerialConfig, UpstreamTlsConfig
from mbgw.config.scenario import parse_scenario
from mbgw.config.slaveid import SlaveIdTable, SlaveRange, parse_fingerprint
from mbgw.errors import ConfigError
from mbgw.net.tls import client_context, server_mismatch
from tests.pki import Authority


def test_a_range_with_tls():
    r = SlaveRange.parse("1 8 1 0 192.168.0.30 TLS")
    assert r == SlaveRange(1, 8, 1, False, ipaddress.IPv4Address("192.168.0.30"), tls=True)
    assert r.line() == "1 8 1 0 192.168.0.30 tls"
    assert SlaveRange.parse(r.line()) == r
    assert str(r) == "1..8 -> 192.168.0.30 unit 1..8 (TLS)"
    assert not SlaveRange.parse("1 8 1 0 192.168.0.30").tls
    with pytest.raises(ConfigError, match="expected 'FS LS FR M IP', 'FS LS FR M IP tls'"):
        SlaveRange.parse("1 8 1 0 192.168.0.30 ssl")


PIN = "sha256 Fingerprint=" + ":".join(f"{b:02X}" for b in range(32))


def test_a_tls_range_pins_a_fingerprint_and_keeps_it_in_its_line():
    r = SlaveRange.parse(f"1 4 1 1 10.0.0.1 tls {PIN.split('=')[1]}")
    assert r.fingerprint == bytes(range(32))
    assert SlaveRange.parse(r.line()) == r
    assert SlaveIdTable([r]).pins == {f"10.0.0.{n}": bytes(range(32)) for n in (1, 2, 3, 4)}
    assert parse_fingerprint("x", PIN) == parse_fingerprint("x", bytes(range(32)).hex()) \
        == bytes(range(32))
    for bad in ("AB:CD", "zz" * 32, "1 8 1 0 10.0.0.1 " + "00" * 32):
        with pytest.raises(ConfigError, match="expected the certificate's SHA-256|expected 'FS"):
            if bad.startswith("1 8"):
                SlaveRange.parse(bad)            # a fingerprint without tls
            else:
                parse_fingerprint("slaveid", bad)


def test_a_server_certificate_is_checked_against_the_address_dialled_or_the_pin(tmp_path):
    ca = Authority(tmp_path)
    cert, _ = ca.issue("server", server=True, names="IP:10.0.0.1, DNS:*.plant.example, "
                                                   "DNS:gw.example")
    der = x509.load_pem_x509_certificate(cert.read_bytes()).public_bytes(Encoding.DER)
    assert server_mismatch(der, "10.0.0.1", None) is None
    assert server_mismatch(der, "gw.example", None) is None
    assert server_mismatch(der, "GW.example.", None) is None
    assert server_mismatch(der, "meter.plant.example", None) is None
    for host in ("10.0.0.2", "a.b.plant.example", "plant.example", "example", "gw"):
        assert server_mismatch(der, host, None) == \
            f"the server's certificate is not for {host}", host
    assert server_mismatch(der, "10.0.0.9", hashlib.sha256(der).digest()) is None
    assert "not the one pinned" in server_mismatch(der, "10.0.0.1", bytes(32))
    assert server_mismatch(None, "10.0.0.1", None) == "the server showed no certificate"


def test_the_table_knows_its_tls_servers_and_refuses_one_server_both_ways():
    table = SlaveIdTable.parse(["1 4 1 1 10.0.0.1 tls", "5 5 1 0 10.0.0.9"])
    assert table.tls_hosts == {"10.0.0.1", "10.0.0.2", "10.0.0.3", "10.0.0.4"}
    with pytest.raises(ConfigError, match="server 10.0.0.3 is reached over TLS by the range "
                                          "1..4 and without by the range 5..5"):
        SlaveIdTable.parse(["1 4 1 1 10.0.0.1 tls", "5 5 1 0 10.0.0.3"])


def scenario(**changes):
    fields = {"name": "remote", "server": "10.0.0.5", "function": 3, "address": 0,
              "quantity": 2, "table": 0, "cycle": 1000, **changes}
    return parse_scenario({k: v for k, v in fields.items() if v is not None}, "scenario 1")


def test_a_tls_scenario_defaults_to_port_802():
    sc = scenario(tls=True)
    assert (sc.tls, sc.server, sc.target) == (True, "10.0.0.5:802", "10.0.0.5:802 unit 1 TLS")
    assert scenario(tls="on", server="10.0.0.5:8802").server == "10.0.0.5:8802"
    assert scenario().server == "10.0.0.5:502" and not scenario().tls
    assert sc.fields()["tls"] is True and "tls" not in scenario().fields()
    assert parse_scenario(sc.fields(), "again") == sc


def test_a_tls_scenario_pins_a_fingerprint():
    sc = scenario(tls=True, fingerprint=PIN)
    assert sc.fingerprint == bytes(range(32))
    assert parse_scenario(sc.fields(), "again") == sc
    with pytest.raises(ConfigError, match="scenario remote: fingerprint: only with tls = true"):
        scenario(fingerprint=PIN)
    with pytest.raises(ConfigError, match="scenario remote: fingerprint 'AB': expected the "):
        scenario(tls=True, fingerprint="AB")


def test_tls_is_for_tcp_scenarios_only():
    with pytest.raises(ConfigError, match="scenario remote: tls: only for a TCP scenario"):
        scenario(server=None, slave=3, tls=True)
    with pytest.raises(ConfigError, match="scenario remote: tls 'maybe': expected true or"):
        scenario(tls="maybe")


def test_the_client_files_go_together():
    with pytest.raises(ConfigError, match="tls-client-cert given without tls-client-key and "
                                          "tls-server-ca"):
        UpstreamTlsConfig(client_cert="c.pem")
    with pytest.raises(ConfigError, match="tls-server-ca given without tls-client-cert and "
                                          "tls-client-key"):
        UpstreamTlsConfig(server_ca="ca.pem")


def test_a_tls_range_or_scenario_needs_the_client_certificate():
    serial = SerialConfig(device="/dev/null")
    with pytest.raises(ConfigError, match="slaveid '1 8 1 0 10.0.0.1 tls': tls needs "
                                          "tls-client-cert"):
        MasterConfig(serial=serial, slaveid=SlaveIdTable.parse(["1 8 1 0 10.0.0.1 tls"]))
    with pytest.raises(ConfigError, match="scenario remote: tls needs tls-client-cert"):
        MasterConfig(serial=serial, slaveid=SlaveIdTable(), scenarios=(scenario(tls=True),))


@pytest.fixture
def ca(tmp_path):
    return Authority(tmp_path)


def test_the_client_context_checks_its_files(ca):
    cert, key = ca.issue("mbgw")
    context = client_context(UpstreamTlsConfig(str(cert), str(key), str(ca.cert)))
    assert context.check_hostname is False and context.verify_mode.name == "CERT_REQUIRED"
    old, _ = ca.issue("old", start="20200101000000Z", end="20210101000000Z")
    with pytest.raises(ConfigError, match=f"tls.client-cert {old}: expired on 2021-01-01"):
        client_context(UpstreamTlsConfig(str(old), str(key), str(ca.cert)))
    _, other_key = ca.issue("other")
    with pytest.raises(ConfigError, match=f"tls.client-key: {other_key} does not match"):
        client_context(UpstreamTlsConfig(str(cert), str(other_key), str(ca.cert)))
    with pytest.raises(ConfigError, match="tls.server-ca /nowhere.pem: cannot be read"):
        client_context(UpstreamTlsConfig(str(cert), str(key), "/nowhere.pem"))


def mbgw(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mbgw", *args], capture_output=True,
                          text=True)


def test_config_set_a_tls_range_and_the_client_files(tmp_path, ca):
    conf = str(tmp_path / "mbgw.toml")
    cert, key = ca.issue("mbgw")
    assert mbgw("config", "set", "serial", "mode", "master", "--config", conf).returncode == 0
    tls_range = ("config", "set", "net", "slaveid", "1", "8", "1", "0", "192.168.0.30", "tls",
                 "--config", conf)
    done = mbgw(*tls_range)
    assert done.returncode != 0
    assert "net.slaveid: the range '1 8 1 0 192.168.0.30 tls' needs tls.client-cert, " \
           "tls.client-key and tls.server-ca" in done.stdout + done.stderr
    for name, path in (("client-cert", cert), ("client-key", key), ("server-ca", ca.cert)):
        done = mbgw("config", "set", "tls", name, str(path), "--config", conf)
        assert done.returncode == 0, done.stderr
    done = mbgw(*tls_range)
    assert done.returncode == 0, done.stderr
    assert mbgw("config", "show", "net", "slaveid", "--config", conf).stdout == \
        "1 8 1 0 192.168.0.30 tls\n"
    done = mbgw("check-config", conf)
    assert done.returncode == 0, done.stdout + done.stderr
    done = mbgw("config", "set", "tls", "client-cert", str(ca.cert.parent / "none.pem"),
                "--config", conf)
    assert done.returncode != 0 and "tls.client-cert" in done.stdout + done.stderr


def test_scenarios_that_reach_one_server_pin_it_alike():
    from mbgw.config.scenario import check_scenarios
    one = scenario(tls=True, fingerprint=PIN)
    other = parse_scenario({**one.fields(), "name": "other", "server": "10.0.0.5:8802",
                            "fingerprint": "00" * 32}, "other")
    assert check_scenarios([one, other], "slave") == [
        "scenario other: fingerprint: server 10.0.0.5 is pinned otherwise by scenario remote "
        "(one certificate per server)"]
    same = parse_scenario({**one.fields(), "name": "same"}, "same")
    assert check_scenarios([one, same], "slave") == []
