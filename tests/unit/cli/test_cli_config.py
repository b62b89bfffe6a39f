"""The configuration commands through click's CliRunner: `mbgw config show|set|unset|default`,
`mbgw check-config`, `mbgw run`, and the --config option of the mode commands.  Only
result.output and result.exit_code are used (click 8.1 and 8.2+ differ in the rest)."""
import os
import tomllib

import click
import pytest
from click.testing import CliRunner

from mbgw.cli import config as cli_config
from mbgw.cli import config_option, config_write, main
from mbgw.cli.options import EX_CONFIG
from mbgw.config import schema as config_keys
from mbgw.config import toml_text as toml_edit
from mbgw.config.schema import SerialOption
from mbgw.errors import ConfigError


def mbgw(*args: str, root: click.Group = main, **env):
    return CliRunner().invoke(root, [str(a) for a in args], prog_name="mbgw", env=env or None)


@pytest.fixture
def conf(tmp_path):
    """A factory-default file in a temporary directory."""
    path = tmp_path / "mbgw.toml"
    result = mbgw("config", "default", "--config", path)
    assert result.exit_code == 0, result.output
    return path


def values(path) -> dict:
    return tomllib.loads(path.read_text())


def without_scenarios(options: dict) -> dict:
    """The options but the file's [[scenario]] tables when it has none."""
    return {k: v for k, v in options.items() if not (k == "scenarios" and v == ())}


def recorder() -> tuple[click.Group, list]:
    """A group whose mode commands record the options they are called with (and the
    reloader each would use on SIGHUP, in the group's `reloaders`)."""
    calls = []
    reloaders = []

    def mode_command(name: str) -> click.Command:
        @click.command(name)
        @click.option("--device", cls=SerialOption, required=True)
        @click.option("--stout", cls=SerialOption, type=click.IntRange(1, 65535), default=600)
        @click.option("--baudrate", cls=SerialOption, type=click.IntRange(50, 4000000),
                      default=9600)
        @click.option("--authip", multiple=True)
        def command(**options):
            calls.append((name, without_scenarios(options)))
            reload = config_option.reloader()
            reloaders.append(reload and (lambda: without_scenarios(reload())))
        return command

    group = click.Group("mbgw", commands={"slave": mode_command("slave"),
                                          "master": mode_command("master")})
    cli_config.register(group)
    group.reloaders = reloaders
    return group, calls


# --- check-config ------------------------------------------------------------------------------

def test_check_config_accepts_the_factory_file(conf):
    result = mbgw("check-config", conf)
    assert result.exit_code == 0, result.output
    assert result.output == f"{conf}: ok (slave mode)\n"


def test_check_config_lists_the_problems_naming_file_and_key(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS0"\nstuot = 700\nbaudrate = 0\n')
    result = mbgw("check-config", path)
    assert result.exit_code == 78
    assert f"mbgw: {path}: serial.stuot: unknown key; did you mean serial.stout?" in result.output
    assert f"mbgw: {path}: serial.baudrate: 0 is not in the range" in result.output


def test_check_config_needs_what_the_mode_requires(tmp_path):
    path = tmp_path / "nodevice.toml"
    path.write_text("[serial]\nstout = 700\n")
    result = mbgw("check-config", path)
    assert result.exit_code == 78
    assert "serial.device: missing; slave mode needs it" in result.output


def test_check_config_missing_file(tmp_path):
    result = mbgw("check-config", tmp_path / "none.toml")
    assert result.exit_code == 78
    assert "no such file (create it with: mbgw config default --config" in result.output


def test_check_config_takes_the_file_options_of_every_command(conf, monkeypatch):
    result = mbgw("check-config", "--config", conf)
    assert (result.exit_code, result.output) == (0, f"{conf}: ok (slave mode)\n")
    monkeypatch.setattr(config_keys, "CONFIG_DIR", conf.parent)
    instance = conf.parent / "ttyUSB1.toml"
    instance.write_text(conf.read_text())
    result = mbgw("check-config", "-i", "ttyUSB1")
    assert (result.exit_code, result.output) == (0, f"{instance}: ok (slave mode)\n")
    result = mbgw("check-config", "--instance", "ttyUSB1", "--config", conf)
    assert result.exit_code == 2 and "give --config or --instance, not both" in result.output
    result = mbgw("check-config", conf, "--config", conf)
    assert result.exit_code == 2 and "give FILE, --config FILE or -i NAME" in result.output


# --- config set / show / unset / default ---------------------------------------------------

@pytest.mark.parametrize("words, written", [
    (["interface", "2wires", "echo"], "rs485 echo"),
    (["interface", "4wires", "slave"], "rs422 slave"),
    (["interface", "rs422", "master"], "rs422"),
    (["dtr", "low"], "low"),
    (["xonxoff", "use"], "use"),
])
def test_set_takes_the_guides_line_words(conf, words, written):
    result = mbgw("config", "set", "serial", *words, "--config", conf)
    assert result.exit_code == 0, result.output
    assert values(conf)["serial"][words[0]] == written


def test_set_rts_flow_warns_until_cts_flow_is_set_too(conf):
    result = mbgw("config", "set", "serial", "rts", "flow", "--config", conf)
    assert result.exit_code == 0, result.output
    assert "warning" in result.output and "serial.rts: rts flow with cts ignore" in result.output
    assert mbgw("check-config", conf).exit_code == 78
    result = mbgw("config", "set", "serial", "cts", "flow", "--config", conf)
    assert result.exit_code == 0 and "warning" not in result.output, result.output
    assert mbgw("check-config", conf).exit_code == 0


def test_set_writes_the_value_and_show_reads_it_back(conf):
    result = mbgw("config", "set", "serial", "stout", "700", "--config", conf)
    assert result.exit_code == 0, result.output
    assert result.output == f"{conf}: serial.stout = 700\n"
    assert values(conf)["serial"]["stout"] == 700
    result = mbgw("config", "show", "serial", "stout", "--config", conf)
    assert result.output == "700\n"
    assert "stout            700\n" in mbgw("config", "show", "serial", "--config", conf).output


def test_set_max_connections_per_ip_in_net(conf):
    result = mbgw("config", "set", "net", "max-connections-per-ip", "2", "--config", conf)
    assert result.exit_code == 0, result.output
    assert values(conf)["net"]["max-connections-per-ip"] == 2
    assert mbgw("check-config", conf).exit_code == 0
    result = mbgw("config", "set", "net", "max-connections-per-ip", "1001", "--config", conf)
    assert result.exit_code == 1
    assert "net.max-connections-per-ip: 1001 is not in the range" in result.output


def test_set_keeps_the_comments(conf):
    before = conf.read_text()
    mbgw("config", "set", "serial", "stout", "700", "--config", conf)
    assert conf.read_text() == before.replace("# stout = 600", "stout = 700")


def test_the_guides_session(conf):
    """The guide's commands, one after the other, and what `show` says then."""
    for words in (["serial", "device", "/dev/ttyS1"], ["serial", "format", "8e1"],
                  ["serial", "stout", "700"], ["serial", "mode", "ascii"],
                  ["net", "authip", "1", "192.168.1.5"], ["net", "authip", "2", "192.168.1.6"],
                  ["net", "exception", "on"], ["net", "slaveid", "5"]):
        result = mbgw("config", "set", *words, "--config", conf)
        assert result.exit_code == 0, (words, result.output)
    shown = mbgw("config", "show", "--config", conf).output
    for line in ("[serial]", "mode             slave", "device           /dev/ttyS1",
                 "protocol         ascii", "format           8e1", "stout            700",
                 "[net]", "slaveid          5", "exception        on",
                 "authip           1 192.168.1.5", "authip           2 192.168.1.6",
                 "bind             (not set)", "[general]", "log-level        info"):
        assert line in shown.splitlines(), line
    assert mbgw("check-config", conf).exit_code == 0


def test_mode_master_clears_the_tables_and_takes_the_guides_slaveid_lines(conf):
    mbgw("config", "set", "net", "authip", "1", "192.168.1.5", "--config", conf)
    mbgw("config", "set", "net", "slaveid", "5", "--config", conf)
    result = mbgw("config", "set", "serial", "mode", "master", "--config", conf)
    assert result.exit_code == 0, result.output
    assert "net.authip back to its default" in result.output
    assert "net.slaveid back to its default" in result.output
    assert "authip" not in values(conf)["net"] and "slaveid" not in values(conf)["net"]
    for line in ("1 8 1 0 192.168.0.30", "9 16 0 1 192.168.20.0", "17 24 31 1 192.168.50.0"):
        result = mbgw("config", "set", "net", "slaveid", *line.split(), "--config", conf)
        assert result.exit_code == 0, result.output
    shown = mbgw("config", "show", "net", "slaveid", "--config", conf).output
    assert shown == "1 8 1 0 192.168.0.30\n9 16 0 1 192.168.20.0\n17 24 31 1 192.168.50.0\n"
    assert mbgw("check-config", conf).output == f"{conf}: ok (master mode)\n"
    mbgw("config", "set", "net", "slaveid", "0", "--config", conf)
    assert values(conf)["net"]["slaveid"] == []


@pytest.mark.parametrize("words, expected", [
    (["serial", "stout", "70000"], "serial.stout: 70000 is not in the range"),
    (["serial", "stuot", "700"], "serial.stuot: unknown key; did you mean serial.stout?"),
    (["net", "authip", "9", "192.168.1.5"], "net.authip: expected an entry 1..8"),
    (["serial", "format", "9x1"], "serial.format: format '9x1'"),
])
def test_set_refuses_a_bad_value_and_leaves_the_file(conf, words, expected):
    before = conf.read_text()
    result = mbgw("config", "set", *words, "--config", conf)
    assert result.exit_code == 1
    assert f"mbgw: {conf}: {expected}" in result.output
    assert conf.read_text() == before


def test_set_refuses_a_bad_group_as_a_usage_error(conf):
    result = mbgw("config", "set", "serail", "stout", "700", "--config", conf)
    assert result.exit_code == 2
    assert "serail" in result.output


def test_set_on_a_broken_file_says_fix_it_first(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("[serial]\nstuot = 7\n")
    result = mbgw("config", "set", "serial", "stout", "700", "--config", path)
    assert result.exit_code == 1
    assert "serial.stuot: unknown key" in result.output and "fix the file first" in result.output


def test_unset_puts_a_key_back_to_its_default_even_a_misspelt_one(conf):
    mbgw("config", "set", "serial", "stout", "700", "--config", conf)
    result = mbgw("config", "unset", "serial", "stout", "--config", conf)
    assert result.exit_code == 0, result.output
    assert "# stout = 600" in conf.read_text() and "stout" not in values(conf)["serial"]
    conf.write_text(conf.read_text().replace("[general]\n", "[general]\nstuot = 7\n"))
    result = mbgw("config", "unset", "general", "stuot", "--config", conf)
    assert result.exit_code == 0, result.output
    assert mbgw("check-config", conf).exit_code == 0


def test_set_creates_a_missing_file_from_the_factory_defaults(tmp_path):
    path = tmp_path / "etc" / "new.toml"
    result = mbgw("config", "set", "serial", "device", "/dev/ttyS2", "--config", path)
    assert result.exit_code == 0, result.output
    assert values(path)["serial"]["device"] == "/dev/ttyS2"
    assert path.read_text().startswith("# mbgw configuration")


def test_show_without_a_file_shows_the_defaults(tmp_path):
    result = mbgw("config", "show", "net", "--config", tmp_path / "none.toml")
    assert result.exit_code == 0
    assert "does not exist: built-in defaults" in result.output
    assert "mdbport          502" in result.output


def test_default_restores_the_factory_file(conf):
    factory = conf.read_text()
    mbgw("config", "set", "serial", "stout", "700", "--config", conf)
    result = mbgw("config", "default", "--config", conf)
    assert result.exit_code == 0
    assert conf.read_text() == factory


def test_instance_files_live_in_the_config_dir(tmp_path, monkeypatch):
    monkeypatch.setattr(config_keys, "CONFIG_DIR", tmp_path)
    result = mbgw("config", "set", "-i", "ttyUSB1", "serial", "device", "/dev/ttyUSB1")
    assert result.exit_code == 0, result.output
    assert values(tmp_path / "ttyUSB1.toml")["serial"]["device"] == "/dev/ttyUSB1"
    assert "apply it with: systemctl reload mbgw@ttyUSB1" in result.output
    assert mbgw("config", "show", "-i", "../x").exit_code == 2


def test_permission_error_says_to_use_sudo(conf, monkeypatch):
    def refuse(*_):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(config_write, "write_atomic", refuse)
    result = mbgw("config", "set", "serial", "stout", "700", "--config", conf)
    assert result.exit_code == 1
    assert (f"cannot write {conf}: permission denied; run it as root: sudo mbgw config set "
            f"serial stout 700 --config {conf}") in result.output


def test_mbgw_config_environment_variable(conf):
    result = mbgw("config", "set", "serial", "stout", "700", MBGW_CONFIG=str(conf))
    assert result.exit_code == 0, result.output
    assert values(conf)["serial"]["stout"] == 700


def test_set_refuses_to_write_over_a_device(conf):
    result = mbgw("config", "set", "serial", "stout", "700", "--config", os.devnull)
    assert result.exit_code == 1
    assert "not a regular file" in result.output


# --- the mode commands and run: command line > file > default -----------------------------

def test_mode_command_takes_what_it_is_not_given_from_the_file(tmp_path):
    group, calls = recorder()
    path = tmp_path / "f.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS5"\nstout = 700\n[net]\n'
                    'authip = ["0.0.0.0", "192.0.2.2"]\n')
    result = mbgw("slave", "--config", path, "--baudrate", "19200", root=group)
    assert result.exit_code == 0, result.output
    assert calls == [("slave", {"device": "/dev/ttyS5", "stout": 700, "baudrate": 19200,
                                "authip": ("192.0.2.2",)})]
    mbgw("slave", "--stout", "800", "--config", path, root=group)
    assert calls[-1][1]["stout"] == 800                       # wherever --config stands
    mbgw("slave", "--stout", "800", root=group, MBGW_CONFIG=str(path))
    assert calls[-1][1]["device"] == "/dev/ttyS5"


def test_mode_command_with_a_bad_file_names_it(tmp_path):
    group, calls = recorder()
    path = tmp_path / "f.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS5"\nstout = 0\n')
    result = mbgw("slave", "--config", path, root=group)
    assert result.exit_code == EX_CONFIG and calls == []
    assert f"mbgw: {path}: serial.stout: 0 is not in the range" in result.output


def test_run_starts_the_mode_the_file_selects(tmp_path):
    group, calls = recorder()
    path = tmp_path / "f.toml"
    path.write_text('[serial]\nmode = "master"\ndevice = "/dev/ttyS6"\n')
    result = mbgw("run", "--config", path, "--stout", "900", root=group)
    assert result.exit_code == 0, result.output
    assert calls == [("master", {"device": "/dev/ttyS6", "stout": 900, "baudrate": 9600,
                                 "authip": ()})]


def test_a_path_that_can_never_be_a_serial_device_is_refused_by_set_check_and_run(conf,
                                                                                 tmp_path):
    before = conf.read_text()
    result = mbgw("config", "set", "serial", "device", str(tmp_path), "--config", conf)
    assert result.exit_code == 1 and f"device {tmp_path}: a directory" in result.output
    assert conf.read_text() == before
    conf.write_text(before.replace('device = "/dev/ttyUSB0"', f'device = "{tmp_path}"'))
    assert f'device = "{tmp_path}"' in conf.read_text()
    result = mbgw("check-config", conf)
    assert result.exit_code != 0 and f"serial.device: device {tmp_path}: a directory, not a " \
        f"serial device" in result.output
    result = mbgw("run", "--config", conf)
    assert result.exit_code == EX_CONFIG
    assert f"serial.device: device {tmp_path}: a directory" in result.output


def test_run_without_a_device_names_the_key(tmp_path):
    group, calls = recorder()
    path = tmp_path / "f.toml"
    path.write_text("[serial]\nstout = 700\n")
    result = mbgw("run", "--config", path, root=group)
    assert result.exit_code == EX_CONFIG and calls == []
    assert f"mbgw: {path}: serial.device: missing; slave mode needs it" in result.output


def test_run_reaches_the_real_slave_mode(conf):
    """mbgw's own slave command gets the file's device (and fails to open it, here: no tty)."""
    mbgw("config", "set", "serial", "device", "/dev/zero", "--config", conf)
    result = mbgw("run", "--config", conf)
    assert result.exit_code == 1
    assert "/dev/zero" in result.output


def test_mode_command_option_wins_over_the_real_file(conf):
    mbgw("config", "set", "serial", "device", "/dev/zero", "--config", conf)
    result = mbgw("slave", "--config", conf, "--device", "/dev/null")
    assert result.exit_code == 1
    assert "/dev/null" in result.output and "/dev/zero" not in result.output


def test_help_of_every_command_works():
    for args in (["run"], ["check-config"], ["config"], ["config", "show"], ["config", "set"],
                 ["config", "unset"], ["config", "default"], ["slave"], ["master"]):
        result = mbgw(*args, "--help")
        assert result.exit_code == 0, (args, result.output)
    assert "--config FILE" in mbgw("slave", "--help").output


def test_dump_of_written_values_is_what_show_reads(conf):
    mbgw("config", "set", "serial", "rtsdelays", "10", "20", "--config", conf)
    assert values(conf)["serial"]["rtsdelays"] == [10, 20]
    assert mbgw("config", "show", "serial", "rtsdelays", "--config", conf).output == "10 20\n"
    assert toml_edit.dump_value([10, 20]) in conf.read_text()


# --- reloading on SIGHUP: the file again, the command line kept ----------------------------

def test_reloader_rereads_the_file_keeping_the_command_line(tmp_path):
    group, calls = recorder()
    path = tmp_path / "f.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS5"\nstout = 700\n')
    assert mbgw("slave", "--config", path, "--baudrate", "19200", root=group).exit_code == 0
    reload = group.reloaders[-1]
    assert reload() == {"mode": "slave", **calls[-1][1]}
    path.write_text('[serial]\ndevice = "/dev/ttyS6"\nstout = 900\nbaudrate = 38400\n')
    assert reload() == {"mode": "slave", "device": "/dev/ttyS6", "stout": 900,
                        "baudrate": 19200, "authip": ()}
    path.write_text('[serial]\ndevice = "/dev/ttyS6"\nstout = 0\n')
    with pytest.raises(ConfigError, match=rf"^{path}: serial.stout: 0 is not in the range"):
        reload()


def test_reloader_takes_a_required_option_from_the_command_line(tmp_path):
    """The device given on the command line need not be in the file, at start or on SIGHUP."""
    group, calls = recorder()
    path = tmp_path / "f.toml"
    path.write_text("[serial]\nstout = 700\n")
    assert mbgw("master", "--config", path, "--device", "/dev/ttyS3", root=group).exit_code == 0
    path.write_text("[serial]\nstout = 800\n")
    assert group.reloaders[-1]() == {"mode": "master", "device": "/dev/ttyS3", "stout": 800,
                                     "baudrate": 9600, "authip": ()}
    assert group.commands["master"].params[0].required      # the command itself unchanged


def test_reloader_after_run_refuses_a_change_of_mode(tmp_path):
    group, calls = recorder()
    path = tmp_path / "f.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS5"\n')
    assert mbgw("run", "--config", path, root=group).exit_code == 0
    path.write_text('[serial]\nmode = "master"\ndevice = "/dev/ttyS5"\n')
    with pytest.raises(ConfigError, match="serial.mode is master now: changing the mode needs "
                                          "a restart"):
        group.reloaders[-1]()


def test_no_reloader_without_a_file(tmp_path, monkeypatch):
    monkeypatch.setattr(config_keys, "DEFAULT_PATH", tmp_path / "absent.toml")
    group, calls = recorder()
    result = mbgw("slave", "--device", "/dev/ttyS1", root=group, MBGW_CONFIG=None)
    assert result.exit_code == 0, result.output
    assert group.reloaders == [None]


def test_a_key_named_as_another_groups_key_is_set_shown_and_unset_in_its_own_group(conf):
    """[transparent] silence is not [serial] silence, [tls] port not [table] port."""
    assert mbgw("config", "set", "serial", "mode", "transparent", "--config", conf).exit_code \
        == 0
    for group, value in (("transparent", "20"), ("tls", "8802"), ("serial", "7")):
        result = mbgw("config", "set", group, ("port" if group == "tls" else "silence"), value,
                      "--config", conf)
        assert result.exit_code == 0, result.output
    data = values(conf)
    assert (data["transparent"]["silence"], data["tls"]["port"], data["serial"]["silence"]) \
        == (20, 8802, 7)
    assert "port" not in data.get("table", {})
    shown = mbgw("config", "show", "transparent", "silence", "--config", conf)
    assert shown.output.strip() == "20"
    assert "silence" in mbgw("config", "show", "transparent", "--config", conf).output
    result = mbgw("config", "unset", "transparent", "silence", "--config", conf)
    assert result.exit_code == 0, result.output
    data = values(conf)
    assert "silence" not in data["transparent"] and data["serial"]["silence"] == 7


def test_net_metric_is_refused_with_its_reason_by_set_and_in_the_file(conf, tmp_path):
    result = mbgw("config", "set", "net", "metric", "10", "--config", conf)
    assert result.exit_code == 1, result.output
    assert "net.metric: not supported: the guide's gateway hop count is a route metric" \
        in result.output, result.output
    hand_edited = tmp_path / "metric.toml"
    hand_edited.write_text(conf.read_text() + "\n[net]\nmetric = 10\n"
                           if "[net]" not in conf.read_text()
                           else conf.read_text().replace("[net]\n", "[net]\nmetric = 10\n", 1))
    result = mbgw("check-config", hand_edited)
    assert result.exit_code == 78, result.output
    assert "net.metric: not supported" in result.output and "CAP_NET_ADMIN" in result.output


@pytest.mark.parametrize("words, expected", [
    (["x" * 31], "general.location: location 'xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx': at most 30"),
    (["Pumpe", "Ölraum"], "general.location: location 'Pumpe Ölraum': printable ASCII only"),
])
def test_location_is_refused_beyond_the_guides_30_ascii_bytes(conf, words, expected):
    result = mbgw("config", "set", "general", "location", *words, "--config", conf)
    assert result.exit_code == 1, result.output
    assert expected in result.output, result.output


def test_location_set_and_shown_in_the_guides_words(conf):
    result = mbgw("config", "set", "general", "location", "Pump", "house", "3", "--config", conf)
    assert result.exit_code == 0, result.output
    assert values(conf)["general"]["location"] == "Pump house 3"
    assert mbgw("config", "show", "general", "location", "--config", conf).output == \
        "Pump house 3\n"


def test_help_shows_the_built_in_defaults_and_what_the_file_in_use_sets(tmp_path):
    path = tmp_path / "site.toml"
    path.write_text('[serial]\ndevice = "/dev/ttyS5"\nstout = 600\n[net]\nmdbport = 1602\n')
    for args, env in ((["slave", "-h"], {"MBGW_CONFIG": str(path)}),
                      (["slave", "--config", path, "-h"], {})):
        result = mbgw(*args, **env)
        assert result.exit_code == 0, result.output
        text = "".join(result.output.split())      # unwrapped (a long path is cut anywhere)
        assert f"[default:502;0<=x<=65535][{path}sets1602]" in text, result.output
        assert f"[required][{path}sets/dev/ttyS5]" in text, result.output
        assert "[default:600;1<=x<=65535][" not in text     # the file sets the default
    result = mbgw("slave", "-h")
    assert "sets" not in result.output or not config_keys.DEFAULT_PATH.exists()


def test_hints_name_the_file_in_use(tmp_path):
    path = tmp_path / "site.toml"
    path.write_text('[serial]\ndevice = "/dev/null"\n[web]\nlisten = "127.0.0.1:8080"\n')
    result = mbgw("check-config", path)
    assert result.exit_code == 78
    assert f"(mbgw config password admin --config {path})" in result.output, result.output
    path.write_text("[serial]\nstout = 700\n")
    result = mbgw("check-config", "--config", path)
    assert f"(e.g. mbgw config set serial device /dev/ttyUSB0 --config {path})" \
        in result.output, result.output
