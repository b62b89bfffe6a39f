"""The authip access list (mbgw.net.acl.AccessList), built the way the daemon builds it: from the
validated SlaveConfig.authip."""
import pytest

from mbgw.config.model import SerialConfig, SlaveConfig
from mbgw.net.acl import AccessList


def _acl(*authip: str) -> AccessList:
    return AccessList(SlaveConfig(SerialConfig("/dev/null"), authip=authip).authip)


@pytest.mark.parametrize("peer", ["192.0.2.7", "::1", "2001:db8::5", "::ffff:192.0.2.7",
                                  "fe80::1%eth0"])
def test_empty_list_allows_everyone(peer):
    assert _acl().allows(peer)


def test_ipv4_entry_allows_that_address_only():
    acl = _acl("192.0.2.7", "198.51.100.1")
    assert acl.allows("192.0.2.7")
    assert acl.allows("198.51.100.1")
    assert not acl.allows("192.0.2.8")
    assert not acl.allows("127.0.0.1")


def test_ipv4_mapped_ipv6_peer_matches_its_ipv4_entry():
    # A dual-stack listener reports IPv4 clients as ::ffff:a.b.c.d.
    acl = _acl("192.0.2.7")
    assert acl.allows("::ffff:192.0.2.7")
    assert not acl.allows("::ffff:192.0.2.8")


def test_ipv4_mapped_entry_matches_the_plain_ipv4_peer():
    acl = _acl("::ffff:192.0.2.7")
    assert acl.allows("192.0.2.7")
    assert acl.allows("::ffff:192.0.2.7")


def test_ipv6_entry_matches_any_spelling_of_that_address():
    acl = _acl("2001:db8::10")
    assert acl.allows("2001:db8::10")
    assert acl.allows("2001:DB8:0:0:0:0:0:10")
    assert not acl.allows("2001:db8::11")


def test_ipv4_entry_does_not_let_in_unrelated_ipv6_peers():
    acl = _acl("127.0.0.1")
    assert not acl.allows("::1")
    assert not acl.allows("::127.0.0.1")        # IPv4-compatible, not IPv4-mapped


def test_scoped_peer_matches_unscoped_link_local_entry():
    # Link-local peers come with their interface, e.g. "fe80::1%eth0".
    acl = _acl("fe80::1")
    assert acl.allows("fe80::1%eth0")
    assert acl.allows("fe80::1")
    assert not acl.allows("fe80::2%eth0")


def test_scoped_link_local_entry_matches_its_peer():
    acl = _acl("fe80::1%eth0")
    assert acl.allows("fe80::1%eth0")
