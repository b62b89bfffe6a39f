"""[[scenario]] tables (mbgw.config.scenario): what each function accepts, and every bad
value refused with a message naming the scenario and the key; the file's loader, check-config
and the mode's limits."""
import subprocess
import sys

import pytest

from mbgw.config.scenario import ScenarioConfig, parse_scenario
from mbgw.errors import ConfigError


def fields(**changes):
    base = {"name": "boiler", "slave": 45, "function": 3, "address": 1000, "quantity": 10,
            "table": 0, "cycle": 3000}
    base.update(changes)
    return {k: v for k, v in base.items() if v is not None}


def test_vpgate_example():
    sc = parse_scenario(fields(), "scenario 1")
    assert sc == ScenarioConfig(name="boiler", function=3, address=1000, quantity=10, table=0,
                                slave=45, cycle_ms=3000)
    assert (sc.kind, sc.reads, sc.writes) == ("serial", True, False)
    assert sc.table_ranges() == [(0, 10, "read")]


def test_tcp_server_forms():
    def server(text):
        return parse_scenario(fields(slave=None, server=text), "s").server
    assert server("192.168.10.45") == "192.168.10.45:502"
    assert server("192.168.10.45:1502") == "192.168.10.45:1502"
    assert server("[fe80::1]:1502") == "[fe80::1]:1502"
    assert server("plc-7.local") == "plc-7.local:502"
    sc = parse_scenario(fields(slave=None, server="h", unit=9), "s")
    assert (sc.kind, sc.unit, sc.target) == ("tcp", 9, "h:502 unit 9")


def test_bit_addresses_register_dot_bit():
    sc = parse_scenario(fields(function=1, address="62.8", quantity=20, table="100.3"), "s")
    assert (sc.address, sc.table) == (62 * 16 + 8, 1603)
    assert sc.table_ranges() == [(100, 2, "read")]     # bits 1603..1622: registers 100, 101
    assert sc.fields()["table"] == "100.3"


def test_change_trigger_and_fc23():
    sc = parse_scenario(fields(function=16, quantity=3, table=500, cycle=None,
                               trigger="change"), "s")
    assert sc.on_change and sc.cycle_ms is None and sc.write_range() == (500, 3)
    sc = parse_scenario(fields(function=23, address=None, quantity=None, table=None,
                               **{"read-address": 1, "read-quantity": 2, "read-table": 10,
                                  "write-address": 7, "write-quantity": 3,
                                  "write-table": 20}), "s")
    assert sc.table_ranges() == [(10, 2, "read"), (20, 3, "write")]
    assert parse_scenario(sc.fields(), "s") == sc


def test_send_unwritten_is_a_writes_key_and_round_trips():
    sc = parse_scenario(fields(function=16, quantity=2, **{"send-unwritten": "on"}), "s")
    assert sc.send_unwritten and sc.fields()["send-unwritten"] is True
    assert parse_scenario(sc.fields(), "s") == sc
    plain = parse_scenario(fields(function=16, quantity=2), "s")
    assert not plain.send_unwritten and "send-unwritten" not in plain.fields()


def test_key_values_as_strings():
    """`mbgw config scenario add NAME KEY=VALUE` and `scenario test` give strings."""
    sc = parse_scenario({"name": "w", "slave": "0", "function": "6", "address": "0x10",
                         "table": "7", "trigger": "change", "enabled": "off"}, "s")
    assert (sc.slave, sc.address, sc.quantity, sc.enabled) == (0, 16, 1, False)


@pytest.mark.parametrize("changes, message", [
    ({"name": None}, "scenario 3: name: missing"),
    ({"name": "a b"}, "scenario 3: name: 'a b': expected 1 to 64 letters"),
    ({"function": 7}, "scenario boiler: function 7: expected one of 1, 2, 3, 4, 5, 6, 15, 16, 23"),
    ({"function": "x"}, "scenario boiler: function 'x': expected a number"),
    ({"slave": None}, "scenario boiler: give slave (a serial scenario) or server"),
    ({"server": "h"}, "scenario boiler: give slave (a serial scenario) or server (a TCP "
                      "scenario), not both"),
    ({"slave": 248}, "scenario boiler: slave 248: out of range 0..247"),
    ({"slave": 0}, "scenario boiler: slave 0: the broadcast address takes writes only"),
    ({"unit": 3}, "scenario boiler: unit: only for a TCP scenario"),
    ({"slave": None, "server": "h:70000"}, "scenario boiler: server 'h:70000': port '70000' "
                                           "out of range 1..65535"),
    ({"slave": None, "server": "h", "unit": 256}, "scenario boiler: unit 256: out of range"),
    ({"quantity": 126}, "scenario boiler: quantity 126: out of range 1..125"),
    ({"quantity": 0}, "scenario boiler: quantity 0: out of range 1..125"),
    ({"function": 1, "quantity": 2001}, "scenario boiler: quantity 2001: out of range 1..2000"),
    ({"function": 15, "quantity": 1969}, "quantity 1969: out of range 1..1968"),
    ({"function": 16, "quantity": 124}, "quantity 124: out of range 1..123"),
    ({"function": 6, "quantity": 2}, "quantity 2: out of range 1..1"),
    ({"address": 65530}, "scenario boiler: quantity 10: from address 65530 it goes beyond"),
    ({"address": 65536}, "scenario boiler: address 65536: out of range 0..65535"),
    ({"table": 0x7FFA}, "scenario boiler: table 32762: a read with quantity 10 would store "
                        "into the configuration zone"),
    ({"function": 1, "table": "4096.0"}, "scenario boiler: table '4096.0': out of range "
                                         "0.0..4095.15"),
    ({"function": 1, "table": "1.16"}, "scenario boiler: table '1.16': expected a number or "
                                       "a bit address"),
    ({"cycle": 99}, "scenario boiler: cycle 99: out of range 100..65535"),
    ({"cycle": 65536}, "scenario boiler: cycle 65536: out of range 100..65535"),
    ({"cycle": None}, "scenario boiler: give cycle (ms, 100..65535) or trigger"),
    ({"trigger": "change"}, "scenario boiler: give cycle (ms, 100..65535) or trigger = "
                            "\"change\", not both"),
    ({"cycle": None, "trigger": "change"}, "scenario boiler: trigger 'change': only a write "
                                           "is sent on change; function 3"),
    ({"cycle": None, "trigger": "edge"}, "scenario boiler: trigger 'edge': expected \"change\""),
    ({"retries": 65536}, "scenario boiler: retries 65536: out of range 0..65535"),
    ({"stale-after": -1}, "scenario boiler: stale-after -1: out of range"),
    ({"function": 16, "stale-after": 500}, "scenario boiler: stale-after 500: only a read"),
    ({"enabled": "maybe"}, "scenario boiler: enabled 'maybe': expected true or false"),
    ({"send-unwritten": True}, "scenario boiler: send-unwritten: only a write sends table "
                               "data (function 5, 6, 15, 16 or 23)"),
    ({"function": 16, "send-unwritten": "sometimes"}, "scenario boiler: send-unwritten "
                                                      "'sometimes': expected true or false"),
    ({"colour": 1}, "scenario boiler: colour: unknown key"),
    ({"function": 23}, "scenario boiler: address: not for function 23 (write read-address"),
    ({"write-table": 1}, "scenario boiler: write-table: not for function 3"),
])
def test_bad_values_name_scenario_and_key(changes, message):
    with pytest.raises(ConfigError) as err:
        parse_scenario(fields(**changes), "scenario 3")
    assert message in str(err.value)


FILE = """[serial]
device = "/dev/null"
{mode}
[[scenario]]
name = "boiler"
slave = 45
function = 3
address = 1000
quantity = 10
table = 0
cycle = 3000

[[scenario]]
name = "remote"
server = "127.0.0.1:1502"
function = 16
address = 0
quantity = 2
table = 100
trigger = "change"
"""


def check_config(tmp_path, text):
    path = tmp_path / "mbgw.toml"
    path.write_text(text)
    return subprocess.run([sys.executable, "-m", "mbgw", "check-config", str(path)],
                          capture_output=True, text=True)


def test_file_scenarios_reach_the_mode_config(tmp_path):
    from mbgw.cli import main
    from mbgw.cli.slave import slave_config
    from mbgw.config.file import load_options
    path = tmp_path / "mbgw.toml"
    path.write_text(FILE.format(mode=""))
    options = load_options(main, path)
    options.pop("mode")
    cfg = slave_config(**options)
    assert [sc.name for sc in cfg.scenarios] == ["boiler", "remote"]
    assert cfg.table_on and not cfg.table.enabled
    assert check_config(tmp_path, FILE.format(mode="")).returncode == 0


def test_file_serial_scenario_in_master_mode(tmp_path):
    done = check_config(tmp_path, FILE.format(mode='mode = "master"'))
    assert done.returncode == 78
    assert "scenario boiler: slave: a serial scenario needs the line's master role" \
        in done.stderr


def test_file_problems_listed_with_their_scenario(tmp_path):
    text = FILE.format(mode="").replace("quantity = 10", "quantity = 200") \
        .replace('"remote"', '"boiler"')
    done = check_config(tmp_path, text)
    assert done.returncode == 78
    # two named boiler: the problem says which
    assert "scenario boiler (the 1st [[scenario]] table): quantity 200: out of range 1..125" \
        in done.stderr
    text = FILE.format(mode="").replace('"remote"', '"boiler"')
    assert "scenario boiler: name used by 2 scenarios (the 1st and 2nd [[scenario]] tables)" \
        in check_config(tmp_path, text).stderr


def test_every_problem_of_a_scenario_is_reported_at_once(tmp_path):
    text = FILE.format(mode="").replace("quantity = 10", "quantity = 200") \
        .replace("cycle = 3000", "cycle = 5").replace("address = 1000", "adress = 1000")
    done = check_config(tmp_path, text)
    assert done.returncode == 78
    problems = [line.split(": ", 2)[2] for line in done.stderr.splitlines()]
    assert problems == ["scenario boiler: adress: unknown key; did you mean address?",
                        "scenario boiler: address: missing",
                        "scenario boiler: cycle 5: out of range 100..65535"], done.stderr


def test_check_config_warns_of_reads_storing_into_the_same_registers(tmp_path):
    second = FILE.format(mode="").split("[[scenario]]")[1].replace('"boiler"', '"boiler2"') \
        .replace("table = 0", "table = 8")
    done = check_config(tmp_path, FILE.format(mode="") + "[[scenario]]" + second)
    assert done.returncode == 0, done.stderr
    assert ": scenario boiler2: stores into table registers 8-9, as scenario boiler " \
           "does: each overwrites the other's data" in done.stderr
    assert done.stderr.startswith("mbgw: warning: ")
    done = check_config(tmp_path, FILE.format(mode=""))
    assert "warning" not in done.stderr


def test_at_most_100_of_a_kind():
    from mbgw.config.scenario import check_scenarios
    many = [parse_scenario(fields(name=f"s{i}"), "s") for i in range(101)]
    assert check_scenarios(many, "slave") == ["scenario: 101 serial scenarios, at most 100"]
    assert check_scenarios(many[:100], "slave") == []


def test_the_manual_lists_every_key_in_order():
    import re

    from mbgw.config.scenario import KEYS
    from tests.harness import CHECKOUT
    page = (CHECKOUT / "docs" / "mbgw.toml.5").read_text()
    section = page.split("\n.SH SCENARIOS\n", 1)[1].split("\n.SH ", 1)[0]
    listed = [k.replace("\\-", "-") for k in re.findall(r"^\.TP\n\.B (\S+)$", section, re.M)]
    assert listed == list(KEYS)


@pytest.mark.parametrize("changes, expected", [
    ({"type": "float32", "quantity": 1},
     "scenario boiler: type 'float32': takes 2 registers, not quantity 1"),
    ({"type": "int16", "quantity": 2},
     "scenario boiler: type 'int16': takes 1 register, not quantity 2"),
    ({"type": "bool", "function": 1, "quantity": 8},
     "scenario boiler: type 'bool': takes 1 bit, not quantity 8"),
    ({"type": "uint32", "function": 1, "quantity": 2},
     "scenario boiler: type 'uint32': a bit scenario's data is bool"),
    ({"type": "double", "quantity": 4},
     "scenario boiler: type 'double': expected one of uint16, int16, uint32, int32, "
     "float32, bool, string"),
    ({"swap": "dcba", "quantity": 2}, "scenario boiler: swap 'dcba': expected one of none, "
                                      "bytes, words"),
    ({"deadband": -1, "quantity": 1}, "scenario boiler: deadband -1: expected a number, 0 or "
                                      "more"),
    ({"type": "string", "deadband": 1}, "scenario boiler: deadband 1: only for a number, not "
                                        "string"),
    ({"type": "uint16", "function": 6, "quantity": None},
     "scenario boiler: type: only a read scenario's data is published"),
])
def test_a_type_the_quantity_does_not_fit_is_refused_naming_the_key(changes, expected):
    with pytest.raises(ConfigError) as err:
        parse_scenario(fields(**changes), "scenario 1")
    assert expected in str(err.value).splitlines()


def test_typed_scenarios_keep_their_keys():
    sc = parse_scenario(fields(quantity=2, type="float32", swap="words", deadband=0.5), "s")
    assert (sc.value_type, sc.swap, sc.deadband) == ("float32", "words", 0.5)
    assert parse_scenario(sc.fields(), "s") == sc
    text = parse_scenario(fields(quantity=6, type="string"), "s")
    assert text.value_type == "string" and text.fields()["type"] == "string"
