"""`mbgw config scenario add|remove` and `mbgw config show scenario`: the file edited as
text (comments and the other tables kept), every change checked like the file."""
import tomllib

import pytest
from click.testing import CliRunner

from mbgw.cli import main

FILE = """# my gateway
[serial]
device = "/dev/ttyUSB0"   # the RS-485 adapter

[[scenario]]
name = "boiler"
slave = 45
function = 3
address = 1000
quantity = 10
table = 0
cycle = 3000

# outputs
[general]
log-level = "info"
"""


@pytest.fixture
def conf(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(FILE)
    return path


def mbgw(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_add_appends_a_checked_scenario(conf):
    result = mbgw("config", "scenario", "add", "valve", "server=192.0.2.7", "function=5",
                  "address=7", "table=100.3", "trigger=change", "--config", conf)
    assert result.exit_code == 0, result.output
    assert f"{conf}: scenario valve added" in result.output
    text = conf.read_text()
    assert text.startswith(FILE)                       # the rest untouched
    assert tomllib.loads(text)["scenario"][1] == {
        "name": "valve", "server": "192.0.2.7:502", "unit": 1, "function": 5,
        "address": "0.7", "quantity": 1, "table": "100.3", "trigger": "change"}


@pytest.mark.parametrize("words, message", [
    (["boiler", "slave=1", "function=3", "address=0", "quantity=1", "table=0", "cycle=100"],
     "scenario boiler: already there"),
    (["x", "slave=1", "function=3", "address=0", "quantity=126", "table=0", "cycle=100"],
     "scenario x: quantity 126: out of range 1..125"),
    (["x", "slave=1", "function=3", "quantity"], "'quantity': expected KEY=VALUE"),
    (["x", "slave=1", "function=3", "addresss=0"], "scenario x: addresss: unknown key"),
])
def test_add_refuses_bad_scenarios(conf, words, message):
    result = mbgw("config", "scenario", "add", *words, "--config", conf)
    assert result.exit_code == 1
    assert message in result.output
    assert conf.read_text() == FILE


def test_add_in_master_mode_refuses_a_serial_scenario(conf):
    conf.write_text('[serial]\nmode = "master"\ndevice = "/dev/ttyUSB0"\n')
    result = mbgw("config", "scenario", "add", "s", "slave=1", "function=3", "address=0",
                  "quantity=1", "table=0", "cycle=100", "--config", conf)
    assert result.exit_code == 1
    assert "scenario s: slave: a serial scenario needs the line's master role" in result.output


def test_remove_keeps_the_rest(conf):
    result = mbgw("config", "scenario", "remove", "boiler", "--config", conf)
    assert result.exit_code == 0, result.output
    assert conf.read_text() == ('# my gateway\n[serial]\ndevice = "/dev/ttyUSB0"   # the '
                                'RS-485 adapter\n\n# outputs\n[general]\nlog-level = "info"\n')
    result = mbgw("config", "scenario", "remove", "boiler", "--config", conf)
    assert result.exit_code == 1 and "no scenario 'boiler'" in result.output


def test_show_scenario(conf):
    result = mbgw("config", "show", "scenario", "--config", conf)
    assert result.exit_code == 0
    assert result.output.splitlines() == [
        "[[scenario]]", 'name = "boiler"', "slave = 45", "function = 3", "address = 1000",
        "quantity = 10", "table = 0", "cycle = 3000"]
    assert mbgw("config", "show", "scenario", "boiler", "--config", conf).output == \
        result.output
    result = mbgw("config", "show", "scenario", "nope", "--config", conf)
    assert result.exit_code == 2 and "no scenario 'nope'" in result.output
