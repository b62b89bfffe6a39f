"""The exchange table's settings (issue 14): the --table... options of `mbgw slave` and `mbgw
master` to cfg.table, their refusals naming the option, and [table] through `mbgw config
set/show` and `mbgw check-config` (click's CliRunner; only output and exit code used)."""
import tomllib

import click
import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.cli.master import master_config
from mbgw.cli.slave import slave_config
from mbgw.config.model import TableConfig

DEVICE = ["--device", "/nonexistent/tty"]
SLAVEID = ["--slaveid", "1 8 1 0 192.168.0.30"]


def mbgw(*args):
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="mbgw")


def config_of(mode: str, *args: str):
    """The configuration the mode command would start with these options (not started)."""
    command = main.commands[mode]
    ctx = command.make_context(mode, [*DEVICE, *args])
    build = slave_config if mode == "slave" else master_config
    return build(**ctx.params)


def test_slave_defaults_leave_the_table_off():
    assert config_of("slave").table == TableConfig()
    assert not TableConfig().enabled and TableConfig().direct


def test_slave_options_build_the_table():
    table = config_of("slave", "--table", "--no-direct", "--table-units", "1,5,200-202",
                      "--table-functions", "3,4,6,16", "--table-persist", "/var/lib/mbgw/t",
                      "--table-persist-interval", "60").table
    assert table == TableConfig(enabled=True, direct=False, units=(1, 5, 200, 201, 202),
                                functions=(3, 4, 6, 16), persist="/var/lib/mbgw/t",
                                persist_interval_s=60)


def test_under_a_unit_the_table_is_kept_in_its_state_directory_by_default(monkeypatch):
    """systemd's StateDirectory= (mbgw.service: /var/lib/mbgw, mbgw@NAME: /var/lib/mbgw/NAME)
    is where the table's file goes when none is given; `off` keeps none."""
    monkeypatch.setenv("STATE_DIRECTORY", "/var/lib/mbgw/gw2")
    for mode, options in (("slave", ()), ("master", SLAVEID)):
        assert config_of(mode, *options, "--table").table.persist == "/var/lib/mbgw/gw2/table"
        assert config_of(mode, *options, "--table-persist", "off").table.persist is None
        assert config_of(mode, *options, "--table-persist", "/var/lib/mbgw/gw2/t") \
            .table.persist == "/var/lib/mbgw/gw2/t"
    monkeypatch.setenv("STATE_DIRECTORY", "/var/lib/a:/var/lib/b")
    assert config_of("slave").table.persist == "/var/lib/a/table"


def test_outside_a_unit_the_table_is_not_kept_unless_told(monkeypatch):
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    assert config_of("slave", "--table").table.persist is None
    assert config_of("slave", "--table-persist", "off").table.persist is None


def test_master_options_build_the_table():
    table = config_of("master", *SLAVEID, "--table", "--table-address", "9",
                      "--table-port", "1502", "--table-functions", "1-7").table
    assert (table.enabled, table.address, table.port) == (True, 9, 1502)
    assert table.functions == (1, 2, 3, 4, 5, 6, 7)


@pytest.mark.parametrize("mode, option, value, reason", [
    ("slave", "--table-units", "0-3", "0 out of range 1..255"),
    ("slave", "--table-units", "256", "256 out of range 1..255"),
    ("slave", "--table-units", "1;2", "'1;2' is not a number or a range"),
    ("slave", "--table-units", "", "empty"),
    ("slave", "--table-functions", "3,8", "8: the table answers only 1, 2, 3"),
    ("master", "--table-functions", "x", "'x' is not a number"),
    ("slave", "--table-persist-interval", "0", "0 is not in the range"),
    ("slave", "--table-persist", "", "empty"),
    ("master", "--table-address", "248", "248 is not in the range 0<=x<=247"),
    ("master", "--table-port", "0", "0 is not in the range"),
])
def test_bad_values_name_the_option_and_why(mode, option, value, reason):
    result = mbgw(mode, *DEVICE, option, value)
    assert result.exit_code == 2, result.output
    assert f"'{option}'" in result.output and reason in result.output


@pytest.mark.parametrize("mode, option", [
    ("master", "--table-units"), ("master", "--direct"), ("slave", "--table-address"),
    ("slave", "--table-port")])
def test_each_mode_has_only_its_own_table_options(mode, option):
    result = mbgw(mode, *DEVICE, option, "1")
    assert result.exit_code == 2 and "No such option" in result.output


def test_master_table_address_in_a_slaveid_range_names_both():
    with pytest.raises(click.BadParameter) as caught:
        config_of("master", *SLAVEID, "--table", "--table-address", "5")
    message = caught.value.format_message()
    assert "'--table-address' / '--slaveid'" in message
    assert "serial address 5 is in the slaveid range 1..8 (1 8 1 0 192.168.0.30)" in message
    assert config_of("master", *SLAVEID, "--table-address", "5").table.address == 5  # table off


def test_help_lists_the_table_options():
    slave = mbgw("slave", "--help").output
    master = mbgw("master", "--help").output
    for option in ("--table / --no-table", "--table-functions LIST", "--table-persist PATH",
                   "--table-persist-interval S"):
        assert option in slave and option in master
    assert "--direct / --no-direct" in slave and "--table-units LIST" in slave
    assert "--table-address N" in master and "--table-port" in master


# --- [table] through mbgw config -----------------------------------------------------------

@pytest.fixture
def conf(tmp_path):
    path = tmp_path / "mbgw.toml"
    assert mbgw("config", "default", "--config", path).exit_code == 0
    return path


def test_factory_file_lists_the_table_keys_commented_out(conf):
    text = conf.read_text()
    assert "\n[table]\n" in text
    for line in ("# enabled = false", "# direct = true", '# units = "247-254"',
                 '# functions = "1,2,3,4,5,6,7,15,16,23"', "# persist =",
                 "# persist-interval = 10", "# address = 0", "# port = 502"):
        assert f"\n{line}\n" in text, line
    assert tomllib.loads(text).get("table", {}) == {}


def test_set_then_show_table(conf):
    for words, said in [(("enabled", "on"), "table.enabled = true"),
                        (("units", "1,5", "200-210"), 'table.units = "1,5,200-210"'),
                        (("functions", "3,4,16"), 'table.functions = "3,4,16"'),
                        (("persist", "/var/lib/mbgw/t"), 'table.persist = "/var/lib/mbgw/t"')]:
        result = mbgw("config", "set", "table", *words, "--config", conf)
        assert result.exit_code == 0, result.output
        assert f"{conf}: {said}\n" in result.output
    assert tomllib.loads(conf.read_text())["table"] == {
        "enabled": True, "units": "1,5,200-210", "functions": "3,4,16",
        "persist": "/var/lib/mbgw/t"}
    assert mbgw("config", "show", "table", "units", "--config", conf).output == "1,5,200-210\n"
    shown = mbgw("config", "show", "table", "--config", conf).output
    assert shown.startswith("[table]\n")
    for line in ("enabled          on", "direct           on", "units            1,5,200-210",
                 "functions        3,4,16", "persist          /var/lib/mbgw/t",
                 "persist-interval 10", "address          0", "port             502"):
        assert f"\n{line}\n" in shown, line
    assert "[table]" in mbgw("config", "show", "--config", conf).output
    assert mbgw("check-config", conf).exit_code == 0
    result = mbgw("config", "unset", "table", "units", "--config", conf)
    assert result.exit_code == 0 and "units" not in tomllib.loads(conf.read_text())["table"]


def test_set_table_refuses_and_leaves_the_file(conf):
    before = conf.read_text()
    result = mbgw("config", "set", "table", "units", "0-3", "--config", conf)
    assert result.exit_code == 1
    assert "table.units: table-units '0-3': 0 out of range 1..255" in result.output
    result = mbgw("config", "set", "table", "unit", "3", "--config", conf)
    assert result.exit_code == 1 and "did you mean table.units?" in result.output
    result = mbgw("config", "show", "table", "unit", "--config", conf)
    assert result.exit_code == 2 and "did you mean table.units?" in result.output
    assert conf.read_text() == before


def test_master_set_table_address_into_a_slaveid_range_is_refused(conf):
    for words in (("serial", "mode", "master"), ("net", "slaveid", "1", "8", "1", "0",
                                                 "192.168.0.30"), ("table", "enabled", "on")):
        assert mbgw("config", "set", *words, "--config", conf).exit_code == 0
    result = mbgw("config", "set", "table", "address", "5", "--config", conf)
    assert result.exit_code == 1
    assert "table.address: serial address 5 is in the slaveid range 1..8" in result.output
    assert mbgw("config", "set", "table", "address", "9", "--config", conf).exit_code == 0
    result = mbgw("config", "set", "net", "slaveid", "9", "12", "1", "0", "192.168.0.31",
                  "--config", conf)
    assert result.exit_code == 1 and "serial address 9 is in the slaveid range 9..12" \
        in result.output


def test_run_passes_the_table_settings(conf):
    """`mbgw run` resolves the file's [table] into the mode command's options (the daemon
    itself is not started: load_options is what run and SIGHUP use)."""
    from mbgw.config import file as cf
    for words in (("serial", "mode", "master"), ("table", "enabled", "on"),
                  ("table", "address", "17"), ("table", "port", "1502")):
        assert mbgw("config", "set", *words, "--config", conf).exit_code == 0
    options = cf.load_options(main, conf)
    assert options.pop("mode") == "master"
    assert options["table_enabled"] and options["table_address"] == 17
    table = master_config(**options).table
    assert (table.enabled, table.address, table.port) == (True, 17, 1502)
    options = cf.load_options(main, conf, ["--table-port", "2502"])
    options.pop("mode")
    assert master_config(**options).table.port == 2502
