"""The firewall's rules as the file gives them (errors naming the rule and key) and as a
client's Guard checks a request (units, functions, the address ranges in the PDU,
read-only); the first rule that selects a client decides."""
import struct

import pytest

from mbgw.config.firewall import FirewallConfig, from_file
from mbgw.firewall.guard import Firewall
from mbgw.ops.metrics_faces import firewall_family


def firewall(text_rules: list[dict], default: str = "allow") -> Firewall:
    cfg, problems = from_file({"firewall": {"default": default}, "rule": text_rules})
    assert problems == []
    return Firewall(cfg)


@pytest.mark.parametrize("data, problem", [
    ({"rule": [{"units": "1-300"}]}, "rule 1.units '1-300': 300 out of range 0..255"),
    ({"rule": [{}, {"functions": [3, 200]}]}, "rule 2.functions '3,200': 200 out of range"),
    ({"rule": [{"client": "10.0.0.1/8"}]}, "rule 1.client '10.0.0.1/8': not a CIDR"),
    ({"rule": [{"listener": "ssl"}]}, "rule 1.listener: expected 'tls' or 'plain'"),
    ({"rule": [{"rol": "operator"}]}, "rule 1.rol: unknown key"),
    ({"rule": [{"read-only": "yes"}]}, "rule 1.read-only: expected true or false"),
    ({"rule": {"units": "1"}}, "[rule]: write [[rule]]"),
    ({"firewall": {"default": "drop"}}, "firewall.default: expected 'allow' or 'deny'"),
])
def test_a_bad_rule_is_named_with_its_key(data, problem):
    _, problems = from_file(data)
    assert len(problems) == 1 and problems[0].startswith(problem), problems


def test_no_rules_allow_everything_without_a_guard():
    assert from_file({}) == (FirewallConfig(), [])
    assert Firewall(None).guard("127.0.0.1", None, "plain") is None


def test_the_first_rule_that_selects_the_client_decides():
    fw = firewall([{"client": "10.0.0.0/8", "units": "1"}, {"client": "10.1.0.0/16"},
                   {"role": "operator", "read-only": True}, {"listener": "tls"}], "deny")
    assert fw.guard("10.1.2.3", None, "plain").rule.index == 1
    assert fw.guard("192.0.2.1", "operator", "tls").rule.index == 3
    assert fw.guard("192.0.2.1", "engineer", "tls") is None          # rule 4 grants all
    assert fw.guard("192.0.2.1", None, "plain").rule is None          # default deny


def test_ipv6_cidr():
    fw = firewall([{"client": ["fd00::/8", "::1"], "read-only": True}], "deny")
    assert fw.guard("::1", None, "plain").rule.index == 1
    assert fw.guard("fd12::5", None, "plain").rule.index == 1
    assert fw.guard("fe80::1", None, "plain").rule is None


def span(function: int, address: int, count: int) -> bytes:
    return struct.pack(">BHH", function, address, count)


@pytest.mark.parametrize("unit, request_pdu, allowed", [
    (1, span(3, 0, 10), True),
    (1, span(3, 5, 6), False),                  # 5..10 runs past 9
    (1, span(3, 100, 100), True),               # the second range
    (2, span(3, 0, 1), False),                  # unit
    (1, span(4, 0, 1), False),                  # function
    (1, span(6, 9, 0xFFFF), True),              # one address, any value
    (1, span(16, 8, 3) + b"\x06" + bytes(6), False),
    (1, struct.pack(">BHHHH", 23, 0, 2, 150, 2), True),
    (1, struct.pack(">BHHHH", 23, 0, 2, 250, 2), False),   # the write range is outside
    (1, b"\x03\x00", False),                    # too short to say which addresses
    (1, b"\x07", False),                        # not in functions
])
def test_a_guard_checks_unit_function_and_the_addresses_in_the_pdu(unit, request_pdu,
                                                                    allowed):
    fw = firewall([{"units": "1", "functions": [3, 6, 16, 23], "registers": "0-9,100-199"}])
    assert fw.guard("127.0.0.1", None, "plain").allows(unit, request_pdu) is allowed


# read-only's allow-list: each read, as a whole PDU
READS = {
    1: span(1, 0, 8), 2: span(2, 0, 8), 3: span(3, 0, 2), 4: span(4, 0, 2),
    7: b"\x07", 11: b"\x0b", 12: b"\x0c", 17: b"\x11",
    20: bytes.fromhex("14 07 06 0001 0000 0001"),          # read file record
    24: struct.pack(">BH", 24, 0x04DE),                     # read FIFO queue
    43: bytes.fromhex("2b 0e 01 00"),                       # read device identification
    **{8: struct.pack(">BHH", 8, 0, 0xA537)},               # return query data
}
READ_DIAGNOSTICS = [0, *range(11, 19)]


@pytest.mark.parametrize("function", sorted(READS))
def test_read_only_allows_each_read_of_its_list(function):
    guard = firewall([{"read-only": True}]).guard("127.0.0.1", None, "plain")
    assert guard.allows(1, READS[function])


@pytest.mark.parametrize("function", [f for f in range(1, 128) if f not in READS])
def test_read_only_refuses_every_other_function(function):
    """Writes, and every code not a read: unknown and user-defined ones (65-72, 100-110),
    often vendor writes or firmware transfers."""
    guard = firewall([{"read-only": True}]).guard("127.0.0.1", None, "plain")
    assert not guard.allows(1, bytes((function,)) + bytes(8))


@pytest.mark.parametrize("sub", range(0, 21))
def test_read_only_allows_only_the_diagnostics_that_read(sub):
    """FC 8/4 (force listen only mode) silences a slave until restarted, 8/1 restarts its
    communications, 8/10 clears its counters."""
    guard = firewall([{"read-only": True}]).guard("127.0.0.1", None, "plain")
    assert guard.allows(1, struct.pack(">BHH", 8, sub, 0)) is (sub in READ_DIAGNOSTICS)


def test_read_only_allows_only_the_mei_type_that_reads_and_whole_pdus():
    guard = firewall([{"read-only": True}]).guard("127.0.0.1", None, "plain")
    assert not guard.allows(1, bytes.fromhex("2b 0d 00 00"))     # CANopen general reference
    assert not guard.allows(1, b"\x08\x00")                      # no whole sub-function
    assert not guard.allows(1, b"\x2b")


def test_read_only_takes_the_writes_out_of_the_functions_a_rule_lists():
    guard = firewall([{"read-only": True, "functions": [3, 6, 8, 16, 65]}]).guard(
        "127.0.0.1", None, "plain")
    assert guard.allows(1, span(3, 0, 1))
    assert guard.allows(1, struct.pack(">BHH", 8, 0, 0))
    for request in (span(4, 0, 1), span(6, 0, 1), struct.pack(">BHH", 8, 4, 0),
                    b"\x41" + bytes(4)):
        assert not guard.allows(1, request), request


def test_a_rule_that_lists_functions_allows_exactly_those():
    guard = firewall([{"functions": [8, 65]}]).guard("127.0.0.1", None, "plain")
    assert guard.allows(1, struct.pack(">BHH", 8, 4, 0))        # not read-only: any sub
    assert guard.allows(1, b"\x41\x00")
    assert not guard.allows(1, span(3, 0, 1))


@pytest.mark.parametrize("request_pdu, allowed", [
    (struct.pack(">BHHH", 22, 5, 0xFF00, 0x0012), True),          # mask write register 5
    (struct.pack(">BHHH", 22, 10, 0xFF00, 0x0012), False),
    (struct.pack(">BH", 24, 9), True),                            # FIFO pointer address
    (struct.pack(">BH", 24, 10), False),
    (struct.pack(">BHHHHB", 23, 0, 2, 8, 2, 4) + bytes(4), True),
    (struct.pack(">BHHHHB", 23, 0, 2, 9, 2, 4) + bytes(4), False),   # writes 9..10
    (struct.pack(">BHHHHB", 23, 9, 2, 0, 2, 4) + bytes(4), False),   # reads 9..10
    (READS[20], False),                                           # file records: not named
    (bytes.fromhex("15 09 06 0004 0007 0001 1234"), False),
    (b"\x16\x00", False),                                          # too short
])
def test_registers_apply_to_every_function_that_carries_an_address(request_pdu, allowed):
    guard = firewall([{"registers": "0-9"}]).guard("127.0.0.1", None, "plain")
    assert guard.allows(1, request_pdu) is allowed


def test_a_rule_with_registers_allows_the_file_records_its_functions_name():
    guard = firewall([{"registers": "0-9", "functions": [3, 20]}]).guard(
        "127.0.0.1", None, "plain")
    assert guard.allows(1, READS[20])
    assert not guard.allows(1, bytes.fromhex("15 09 06 0004 0007 0001 1234"))


def test_a_broadcast_is_refused_under_read_only_or_limited_units():
    fw = firewall([{"client": "10.0.0.1", "read-only": True},
                   {"client": "10.0.0.2", "units": "1-10"},
                   {"client": "10.0.0.3", "units": "0-10"},
                   {"client": "10.0.0.4", "registers": "0-9"}])
    write = struct.pack(">BHH", 6, 5, 1)
    assert not fw.guard("10.0.0.1", None, "plain").allows(0, span(3, 0, 1))
    assert not fw.guard("10.0.0.2", None, "plain").allows(0, write)
    assert fw.guard("10.0.0.3", None, "plain").allows(0, write)      # unit 0 listed
    assert fw.guard("10.0.0.4", None, "plain").allows(0, write)


def test_a_tls_client_without_a_role_may_do_nothing_when_roles_are_required():
    cfg, _ = from_file({"rule": [{"client": "127.0.0.1"}]})
    fw = Firewall(cfg, require_role=True)
    guard = fw.guard("127.0.0.1", None, "tls")
    assert guard.label == "no-role"
    assert not guard.allows(1, span(3, 0, 1))
    assert fw.refused(guard, "127.0.0.1:5000", None, 1, span(3, 0, 1)) == b"\x83\x01"
    assert fw.report()["refused_no_role"] == 1 and fw.configured
    assert fw.guard("127.0.0.1", "operator", "tls") is None
    assert fw.guard("127.0.0.1", None, "plain") is None
    assert Firewall(cfg).guard("127.0.0.1", None, "tls") is None
    samples = {s.labels["rule"]: s.value for s in firewall_family(fw.report()).samples}
    assert samples["no-role"] == 1


def test_refusals_are_counted_by_rule_and_the_reply_is_0x01():
    fw = firewall([{"client": "127.0.0.1", "units": "1"}], "deny")
    guard = fw.guard("127.0.0.1", None, "plain")
    assert fw.refused(guard, "127.0.0.1:5000", None, 2, span(3, 0, 1)) == b"\x83\x01"
    fw.refused(fw.guard("::1", None, "plain"), "[::1]:5000", None, 1, span(3, 0, 1))
    report = fw.report([("127.0.0.1:5000", None, 1)])
    assert report["rules"][0]["refused"] == 1 and report["refused_default"] == 1
    samples = {s.labels["rule"]: s.value for s in firewall_family(report).samples}
    assert samples == {"1": 1, "default": 1}


def test_a_reload_with_the_same_rules_keeps_the_counts():
    fw = firewall([{"units": "1"}])
    assert fw.renewed(fw.cfg) is fw
    assert fw.renewed(FirewallConfig()) is not fw
