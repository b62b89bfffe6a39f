"""The role in a client certificate's extension 1.3.6.1.4.1.50316.802.1 (a DER UTF8String),
and the [tls] settings' rules."""
import pytest

from mbgw.config.model import SerialConfig, SlaveConfig, TlsConfig
from mbgw.errors import ConfigError
from mbgw.ops.tls import _utf8_string


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
