"""The role in a client certificate's extension 1.3.6.1.4.1.50316.802.1 (a DER UTF8String),
and the [tls] settings' rules."""
import ssl

import pytest

from mbgw.config.model import SerialConfig, SlaveConfig, TlsConfig
from mbgw.errors import ConfigError
from mbgw.net.tls import _utf8_string, role_of, server_context


@pytest.mark.parametrize("der, role", [
    (b"\x0c\x08operator", "operator"),
    (b"\x0c\x00", ""),
    (b"\x0c\x81\x80" + b"r" * 128, "r" * 128),        # long form length
    (b"\x13\x08operator", None),                      # a PrintableString is no role
    (b"\x0c\x09operator", None),                      # length beyond the bytes
    (b"\x0c\x02\xff\xfe", None),                      # not UTF-8
    (b"", None),
])
def test_role_is_a_der_utf8string(der, role):
    assert _utf8_string(der) == role


def test_tls_needs_key_and_ca_with_a_certificate():
    with pytest.raises(ConfigError, match="tls-cert given without tls-key and tls-ca"):
        TlsConfig(cert="/c.pem")
    with pytest.raises(ConfigError, match="without tls-cert"):
        TlsConfig(ca="/ca.pem")
    assert TlsConfig(cert="/c", key="/k", ca="/ca").enabled and not TlsConfig().enabled


def test_mdbport_0_needs_tls():
    serial = SerialConfig("/dev/null")
    with pytest.raises(ConfigError, match="mdbport 0"):
        SlaveConfig(serial, mdbport=0)
    SlaveConfig(serial, mdbport=0, tls=TlsConfig(cert="/c", key="/k", ca="/ca"))


def test_the_server_context_offers_aead_with_ecdhe_only_the_ccm_suites_and_no_renegotiation(
        tmp_path):
    from tests.pki import Authority
    ca = Authority(tmp_path)
    cert, key = ca.issue("server", server=True)
    context = server_context(TlsConfig(cert=str(cert), key=str(key), ca=str(ca.cert)))
    assert context.options & ssl.OP_NO_RENEGOTIATION
    assert context.minimum_version == ssl.TLSVersion.TLSv1_2
    names = [c["name"] for c in context.get_ciphers()]
    assert "TLS_AES_128_CCM_SHA256" in names and "ECDHE-ECDSA-AES128-CCM8" in names
    tls12 = [c for c in context.get_ciphers() if c["protocol"] == "TLSv1.2"]
    assert tls12 and all(c["kea"] == "kx-ecdhe" and c["aead"] for c in tls12), tls12


def test_an_out_of_date_crl_is_logged_as_an_error(tmp_path, caplog):
    from tests.pki import Authority
    ca = Authority(tmp_path)
    cert, key = ca.issue("server", server=True)
    crl = ca.crl(tmp_path / "ca.crl", hours=-1)
    server_context(TlsConfig(cert=str(cert), key=str(key), ca=str(ca.cert), crl=str(crl)))
    assert [r.levelname for r in caplog.records if "past its next update" in r.message] == \
        ["ERROR"]
    caplog.clear()
    fresh = ca.crl(tmp_path / "fresh.crl")
    context = server_context(TlsConfig(cert=str(cert), key=str(key), ca=str(ca.cert),
                                       crl=str(fresh)))
    assert context.verify_flags & ssl.VERIFY_CRL_CHECK_LEAF and not caplog.records
    with pytest.raises(ConfigError, match="tls-crl given without tls-cert"):
        TlsConfig(crl=str(fresh))


@pytest.mark.parametrize("der, role", [(None, None), (b"", None)])
def test_no_certificate_no_role(der, role):
    assert role_of(der) is role
