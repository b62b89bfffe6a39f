"""The firewall's rules as the file gives them (errors naming the rule and key) and as a
client's Guard checks a request (units, functions, the address ranges in the PDU,
read-only); the first rule that selects a client decides."""
import struct

import pytest

from mbgw.config.firewall import FirewallConfig, from_file
from mbgw.firewall.guard import Firewall
from mbgw.ops.metrics import firewall_family


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


def test_read_only_refuses_every_write_function():
    guard = firewall([{"read-only": True}]).guard("127.0.0.1", None, "plain")
    for function in (5, 6, 15, 16, 21, 22, 23):
        assert not guard.allows(1, bytes((function,)) + bytes(8)), function
    for function in (1, 2, 3, 4, 7, 8, 17, 43):
        assert guard.allows(1, bytes((function,)) + bytes(8)), function


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
