"""The configuration file (mbgw.config.schema, config_file, config_values, config_set,
config_text, toml_edit): keys derived from the commands, checks naming file, key and reason,
the ACKSYS `set` semantics, text edits that keep comments, the atomic write.  The guide is
/work/shared/seeds/000 (ACKSYS MODBUS TCP user guide A.5)."""
import os
import re
import stat
import tomllib

import click
import pytest

from mbgw.cli import main
from mbgw.cli.serial_options import serial_options
from mbgw.config import edit as config_set
from mbgw.config import file as cf
from mbgw.config import schema as config_keys
from mbgw.config import text as config_text
from mbgw.config import toml_text as toml_edit
from mbgw.config.model import LineFormat, TableConfig
from mbgw.config.number_list import number_list_text, parse_number_list
from mbgw.config.slaveid import SlaveRange
from mbgw.errors import ConfigError, ConfigFileError

GUIDE_SLAVEID = ["1 8 1 0 192.168.0.30", "9 16 0 1 192.168.20.0", "17 24 31 1 192.168.50.0"]


@pytest.fixture
def schema() -> config_keys.Schema:
    return config_keys.Schema(main)


def write(tmp_path, text: str, name: str = "mbgw.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def problems(schema, tmp_path, text: str) -> str:
    path = write(tmp_path, text)
    with pytest.raises(ConfigFileError) as caught:
        cf.check(schema, path, tomllib.loads(text))
    message = str(caught.value)
    assert all(line.startswith(f"{path}: ") for line in message.splitlines()), message
    return message


# --- keys come from the commands --------------------------------------------------------------

def test_every_long_option_of_both_modes_is_a_key(schema):
    """...but the hidden ones, switches for diagnosis that no configuration file keeps; a
    table option is its own key in [table] (--table-units is table.units)."""
    own_keys = (config_keys.TableOption, config_keys.TransparentOption)   # [web] too
    params = [p for mode in ("slave", "master", "transparent") for p in main.commands[mode].params
              if isinstance(p, click.Option) and not p.hidden]
    options = {o[2:] for p in params if not isinstance(p, own_keys)
               for o in p.opts if o.startswith("--")}
    table = {p.key for p in params if type(p) is config_keys.TableOption}
    assert table == {"enabled", "direct", "units", "functions", "serial-functions", "address",
                     "port", "persist", "persist-interval", "table-max-connections"}
    transparent = {p.key for p in params if isinstance(p, config_keys.TransparentOption)}
    assert transparent == {"eof", "eof-char", "eof-timeout", "rx-address", "rx-size",
                           "tx-address", "tx-size", "crc", "trigger", "transparent-silence",
                           "raw-port"}
    assert all(schema.keys[k].group == "transparent" for k in transparent)
    tls = {p.key for p in params if type(p) is config_keys.TlsOption}
    assert tls == {"tls-port", "cert", "key", "ca", "require-role", "crl", "client-cert",
                   "client-key", "server-ca", "server-port"}
    web = {p.key for mode in ("slave", "master", "transparent")
           for p in main.commands[mode].params if isinstance(p, config_keys.WebOption)}
    assert web == {"web", "web-cert", "web-key", "admin-password", "user-password",
                   "web-https-only"}
    assert all(schema.keys[k].group == "web" for k in web)
    mqtt = {p.key for mode in ("slave", "master", "transparent")
            for p in main.commands[mode].params if isinstance(p, config_keys.MqttOption)}
    assert mqtt == {f"mqtt-{k}" for k in ("broker", "profile", "group", "node", "role",
                                          "primary-host", "cert", "key", "ca", "stale-after")}
    assert all(schema.keys[k].group == "mqtt" for k in mqtt)
    assert set(schema.keys) == (options - {"config"}) | table | transparent | tls | web | mqtt
    # in the file, a key's name may be another group's too: [tls] port, [transparent] silence
    assert schema.label("tls-port") == "tls.port" and schema.find("tls", "port").name == \
        "tls-port"
    assert schema.find("transparent", "silence").name == "transparent-silence"
    assert schema.find("serial", "interframe-silence").name == "interframe-silence"
    assert schema.find("serial", "silence").name == "silence"
    assert "shortcut" not in schema.keys


@pytest.mark.parametrize("name, group", [
    ("device", "serial"), ("baudrate", "serial"), ("format", "serial"), ("stout", "serial"),
    ("protocol", "serial"), ("silence", "serial"), ("nocheck", "serial"),
    ("interface", "serial"), ("rtsdelays", "serial"),
    ("slaveid", "net"), ("authip", "net"), ("mdbport", "net"), ("exception", "net"),
    ("bind", "net"), ("max-connections", "net"), ("max-connections-per-ip", "net"),
    ("tcpto", "net"), ("retries", "serial"), ("late-window", "serial"),
    ("turnaround", "serial"), ("down-after", "serial"), ("probe-interval", "serial"),
    ("log-level", "general"),
])
def test_keys_are_grouped_like_the_guide(schema, name, group):
    assert schema.keys[name].group == group


def test_a_new_option_is_a_new_key_with_nothing_to_list():
    """A serial option (one of mbgw.cli.serial_options.serial_options) goes to [serial], another to
    [general]; both appear in the factory file at their defaults."""
    @click.command("slave")
    @serial_options
    @click.option("--frobnicate-ms", type=click.IntRange(0, 9), default=3)
    def slave(**_):
        pass
    schema = config_keys.Schema(click.Group("g", commands={"slave": slave}))
    assert schema.keys["frobnicate-ms"].group == "general"
    assert schema.keys["silence"].group == "serial"
    assert "# frobnicate-ms = 3" in config_text.factory_text(schema)


def test_every_serial_option_is_in_serial(schema):
    serial = {o[2:] for p in serial_options(lambda: None).__click_params__ for o in p.opts
              if o.startswith("--")}
    assert serial and serial <= set(schema.group_keys("serial"))


def test_master_keys_join_the_slave_keys(schema):
    assert schema.modes == ("slave", "master", "transparent")
    assert schema.keys["tcpto"].group == "net"
    assert set(schema.keys["slaveid"].params) == {"slave", "master"}


# --- the factory file (what the package installs as /etc/mbgw/mbgw.toml) ------------------

def test_factory_file_is_valid_and_lists_every_key(schema, tmp_path):
    text = config_text.factory_text(schema)
    settings = cf.check(schema, tmp_path / "f.toml", tomllib.loads(text))
    assert settings.mode == "slave"
    assert settings.values == {"device": config_keys.FACTORY_DEVICE}
    options = cf.resolve(schema, settings)
    assert options["device"] == config_keys.FACTORY_DEVICE and options["stout"] == 600
    lines = text.splitlines()
    for name in map(schema.file_name, schema.keys):
        if name.endswith("-password"):      # secrets: never listed, set by config password
            continue
        assert any(line.startswith((f"{name} =", f"# {name} =")) for line in lines), name


# --- load_options: what the daemon calls on SIGHUP -------------------------------------------

def test_load_options_precedence_command_line_then_file_then_default(tmp_path):
    path = write(tmp_path, '[serial]\ndevice = "/dev/ttyS3"\nstout = 700\nformat = "8e1"\n'
                           '[net]\nauthip = ["192.0.2.1", "0.0.0.0", "192.0.2.3"]\n')
    options = cf.load_options(main, path)
    assert options["mode"] == "slave"
    assert options["device"] == "/dev/ttyS3"
    assert options["stout"] == 700                       # file over default
    assert options["line_format"] == LineFormat(8, "e", 1)   # through the option's callback
    assert options["baudrate"] == 9600                   # built-in default
    assert options["authip"] == ("192.0.2.1", "192.0.2.3")   # cleared entries left out
    options = cf.load_options(main, path, ["--stout", "800", "--device", "/dev/ttyS4"])
    assert options["stout"] == 800 and options["device"] == "/dev/ttyS4"
    assert set(options) == {"mode", *(p.name for p in main.commands["slave"].params
                                      if p.expose_value)}


def test_load_options_errors_name_file_key_reason(tmp_path):
    path = write(tmp_path, '[serial]\ndevice = "/dev/ttyS3"\nstout = 0\n')
    with pytest.raises(ConfigError, match=rf"^{path}: serial.stout: 0 is not in the range"):
        cf.load_options(main, path)
    with pytest.raises(ConfigFileError, match="no such file"):
        cf.load_options(main, tmp_path / "absent.toml")


def test_load_options_needs_the_device(tmp_path):
    with pytest.raises(ConfigFileError, match=r"serial.device: missing; slave mode needs it"):
        cf.load_options(main, write(tmp_path, "[serial]\nstout = 700\n"))


def test_tables_belong_to_their_mode(schema, tmp_path):
    path = write(tmp_path, '[serial]\nmode = "master"\ndevice = "/dev/ttyS1"\n'
                           f'[net]\nslaveid = {toml_edit.dump_value(GUIDE_SLAVEID)}\n')
    settings = cf.load(schema, path)
    table = cf.resolve(schema, settings)["slaveid"]          # master's option made it a table
    assert [(r.first, r.last) for r in table.ranges] == [(1, 8), (9, 16), (17, 24)]
    assert "slaveid" not in settings.default_map(schema, "slave")
    assert settings.default_map(schema, "slave")["device"] == "/dev/ttyS1"


# --- unknown keys, bad values ----------------------------------------------------------------

@pytest.mark.parametrize("text, expected", [
    ("[serial]\nstuot = 700\n", "serial.stuot: unknown key; did you mean serial.stout?"),
    ("[net]\nauthpi = []\n", "net.authpi: unknown key; did you mean net.authip?"),
    ("[net]\nmax_connections = 3\n", "did you mean net.max-connections?"),
    ("[serial]\nfoo = 1\n", "serial.foo: unknown key"),
    ("[seral]\nstout = 700\n", "[seral]: unknown group (groups: serial, net, general, table, "
                               "tls, transparent, web, mqtt); did you mean [serial]?"),
    ("[net]\nstout = 700\n", "net.stout: belongs in [serial] (serial.stout)"),
    ("stout = 700\n", "stout: outside any group; put it under [serial]"),
    ("mode = 'slave'\n", "mode: outside any group; put it under [serial]"),
    ("serial = 3\n", "serial: expected a group [serial], not a value"),
])
def test_unknown_keys_are_errors_with_a_hint(schema, tmp_path, text, expected):
    assert expected in problems(schema, tmp_path, text)


@pytest.mark.parametrize("text, expected", [
    ("[serial]\nstout = 70000", "serial.stout: 70000 is not in the range 1<=x<=65535"),
    ("[serial]\nstout = 0", "serial.stout: 0 is not in the range"),
    ("[serial]\nstout = '700'", "serial.stout: expected an integer, got \"700\""),
    ("[serial]\nstout = 7.5", "serial.stout: expected an integer, got 7.5"),
    ("[serial]\nstout = [700]", "serial.stout: expected a single value, not a list"),
    ("[serial]\nstout = {a = 1}", "serial.stout: expected a value, not a table"),
    ("[serial]\nbaudrate = 'fast'", "serial.baudrate: expected an integer"),
    ("[serial]\nbaudrate = 49", "serial.baudrate: 49 is not in the range"),
    ("[serial]\nformat = '9x1'", "serial.format: format '9x1': expected data bits"),
    ("[serial]\nformat = 801", "serial.format: expected a string, got 801"),
    ("[serial]\nprotocol = 'tcp'", "serial.protocol: 'tcp' is not one of 'rtu', 'ascii'"),
    ("[serial]\ninterface = 'rs232 echo'", "serial.interface: interface 'rs232 echo'"),
    ("[serial]\nrtsdelays = [1]", "serial.rtsdelays: expected a list of 2 values"),
    ("[serial]\nrtsdelays = [1, 256]", "serial.rtsdelays: 256 is not in the range"),
    ("[serial]\nnocheck = 'yes'", "serial.nocheck: expected true or false, got \"yes\""),
    ("[serial]\nnocheck = 1", "serial.nocheck: expected true or false, got 1"),
    ("[serial]\nmode = 'rtu'", "serial.mode: 'rtu' is the framing: write protocol = \"rtu\""),
    ("[serial]\nmode = 'both'",
     "serial.mode: expected 'slave' or 'master' or 'transparent', got 'both'"),
    ("[net]\nslaveid = 248", "net.slaveid: 248 is not in the range 0<=x<=247"),
    ("[net]\nauthip = '192.0.2.1'", "net.authip: expected a list of addresses"),
    ("[net]\nauthip = ['192.0.2.1', 'nope']", "net.authip[2]: authip 'nope': not an IP"),
    ("[net]\nauthip = ['192.0.2.1', 5]", "net.authip[2]: expected an address string, got 5"),
    ("[net]\nauthip = " + str([f"192.0.2.{i}" for i in range(9)]),
     "net.authip: 9 entries, the table holds 8"),
    ("[net]\nmdbport = 65536", "net.mdbport: 65536 is not in the range"),
    ("[general]\nlog-level = 'loud'", "general.log-level: 'loud' is not one of"),
])
def test_bad_values_name_the_key_and_the_reason(schema, tmp_path, text, expected):
    assert expected in problems(schema, tmp_path, text)


def test_all_problems_are_reported_at_once(schema, tmp_path):
    message = problems(schema, tmp_path, "[serial]\nstout = 0\nbaudrate = 1\n[net]\nfoo = 2\n")
    assert len(message.splitlines()) == 3


def test_toml_syntax_error_names_file_and_line(schema, tmp_path):
    path = write(tmp_path, "[serial]\nstout = \n")
    with pytest.raises(ConfigFileError, match=rf"^{path}: not valid TOML: .*line 2"):
        cf.load(schema, path)


def test_master_table_entries_are_checked_one_by_one(schema, tmp_path):
    text = ('[serial]\nmode = "master"\n[net]\nslaveid = ["1 8 1 0 192.168.0.30", '
            '"5 9 0 0 10.0.0.1", "9 2 0 0 10.0.0.2", "1 2 3", "0", 7]\n')
    message = problems(schema, tmp_path, text)
    assert "net.slaveid[2]: addresses 5..9 overlap net.slaveid[1] (1..8)" in message
    assert "net.slaveid[3]: slaveid '9 2 0 0 10.0.0.2'" in message
    assert "net.slaveid[4]: slaveid '1 2 3'" in message
    assert "net.slaveid[5]: FS 0 clears the table: leave the list empty instead" in message
    assert "net.slaveid[6]: expected a string" in message


def test_master_table_of_nine_ranges_is_refused(schema, tmp_path):
    entries = [f"{a} {a} 0 0 10.0.0.1" for a in range(1, 10)]
    message = problems(schema, tmp_path, '[serial]\nmode = "master"\n[net]\nslaveid = '
                                         + toml_edit.dump_value(entries))
    assert "net.slaveid: " in message and "8 ranges" in message


# --- the guide's set syntax --------------------------------------------------------------

def settings_of(schema, text: str = "", tmp_path=None) -> cf.Settings:
    return cf.check(schema, "mbgw.toml", tomllib.loads(text))


def do_set(schema, text, group, name, *words):
    """`set GROUP PARAM WORDS` on a file text: the new file's values, checked."""
    data = tomllib.loads(text)
    changes = config_set.changes_for_set(schema, cf.check(schema, "f", data), group, name,
                                         list(words))
    new_data = config_set.apply_changes(data, schema, changes)
    new_text = config_text.edit(text, schema, changes.get("mode", "slave"), changes)
    assert tomllib.loads(new_text) == new_data
    return cf.check(schema, "f", new_data).values, new_text


@pytest.mark.parametrize("words, value", [
    (("serial", "stout", "700"), 700),
    (("serial", "format", "8e1"), "8e1"),
    (("serial", "format", "8E1"), "8e1"),
    (("serial", "format", "8", "e", "1"), "8e1"),
    (("serial", "interface", "rs485", "echo"), "rs485 echo"),
    (("serial", "rtsdelays", "10", "20"), [10, 20]),
    (("serial", "nocheck", "on"), True),
    (("serial", "nocheck", "off"), False),
    (("net", "exception", "on"), True),
    (("serial", "baudrate", "19200"), 19200),
    (("serial", "device", "/dev/ttyS1"), "/dev/ttyS1"),
    (("net", "slaveid", "5"), 5),
    (("net", "bind", "127.0.0.1"), "127.0.0.1"),
    (("general", "log-level", "debug"), "debug"),
])
def test_set_takes_the_guides_words(schema, words, value):
    group, name, *rest = words
    values, _ = do_set(schema, "", group, name, *rest)
    assert values[name] == value


@pytest.mark.parametrize("words, expected", [
    (("serial", "stout", "70000"), "serial.stout: 70000 is not in the range"),
    (("serial", "stout", "soon"), "serial.stout: expected an integer, got 'soon'"),
    (("serial", "stout", "1", "2"), "serial.stout: expected one value"),
    (("serial", "nocheck", "maybe"), "serial.nocheck: expected on or off"),
    (("serial", "rtsdelays", "1"), "serial.rtsdelays: expected 2 values, got 1"),
    (("serial", "stuot", "7"), "serial.stuot: unknown key; did you mean serial.stout?"),
    (("net", "stout", "7"), "net.stout: belongs in [serial]: mbgw config set serial stout"),
    (("serial", "stout"), "serial.stout: expected a value"),
    (("serial", "mode", "tcp"), "serial.mode: 'tcp' is not a mode"),
    (("net", "slaveid", "1", "8", "1", "0", "192.168.0.30"),
     "in slave mode, one serial address (the table FS LS FR M IP is master mode's"),
])
def test_set_refuses_what_the_command_line_refuses(schema, words, expected):
    group, name, *rest = words
    with pytest.raises(ConfigError) as caught:
        do_set(schema, "", group, name, *rest)
    assert expected in str(caught.value)


def test_set_serial_mode_rtu_or_ascii_is_the_protocol(schema):
    values, _ = do_set(schema, "", "serial", "mode", "ascii")
    assert values == {"protocol": "ascii"}


def test_authip_entries_1_to_8_and_0000_clears(schema):
    text = ""
    for entry, address in [("1", "192.168.1.5"), ("3", "192.168.1.7"), ("8", "10.0.0.8")]:
        values, text = do_set(schema, text, "net", "authip", entry, address)
    assert values["authip"] == ["192.168.1.5", "0.0.0.0", "192.168.1.7", "0.0.0.0",
                                "0.0.0.0", "0.0.0.0", "0.0.0.0", "10.0.0.8"]
    values, text = do_set(schema, text, "net", "authip", "1", "192.168.1.6")
    assert values["authip"][0] == "192.168.1.6"
    values, text = do_set(schema, text, "net", "authip", "8", "0.0.0.0")
    assert values["authip"] == ["192.168.1.6", "0.0.0.0", "192.168.1.7"]
    for entry in ("1", "3"):
        values, text = do_set(schema, text, "net", "authip", entry, "0.0.0.0")
    assert values["authip"] == []
    values, text = do_set(schema, text, "net", "authip", "2", "2001:db8::1")
    assert values["authip"] == ["0.0.0.0", "2001:db8::1"]


@pytest.mark.parametrize("words, expected", [
    (("9", "192.168.1.5"), "expected an entry 1..8"),
    (("0", "192.168.1.5"), "expected an entry 1..8"),
    (("192.168.1.5",), "expected an entry 1..8"),
    (("1", "192.168.1"), "net.authip[1]: '192.168.1' is not an IP address"),
])
def test_authip_refuses(schema, words, expected):
    with pytest.raises(ConfigError, match=re.escape(expected)):
        do_set(schema, "", "net", "authip", *words)


MASTER = '[serial]\nmode = "master"\ndevice = "/dev/ttyS1"\n'


def test_slaveid_table_the_guides_three_examples(schema):
    text = MASTER
    for entry in GUIDE_SLAVEID:
        values, text = do_set(schema, text, "net", "slaveid", *entry.split())
    assert values["slaveid"] == GUIDE_SLAVEID
    ranges = [SlaveRange.parse(e) for e in values["slaveid"]]
    assert [(r.first, r.last, r.remote_first, r.variable_ip, str(r.ip)) for r in ranges] == [
        (1, 8, 1, False, "192.168.0.30"), (9, 16, 0, True, "192.168.20.0"),
        (17, 24, 31, True, "192.168.50.0")]


def test_slaveid_fs_inside_a_range_replaces_it(schema):
    text = MASTER + f"[net]\nslaveid = {toml_edit.dump_value(GUIDE_SLAVEID)}\n"
    values, text = do_set(schema, text, "net", "slaveid", "12", "14", "0", "0", "10.0.0.1")
    assert values["slaveid"] == [GUIDE_SLAVEID[0], GUIDE_SLAVEID[2], "12 14 0 0 10.0.0.1"]


def test_slaveid_fs_0_clears_the_table(schema):
    text = MASTER + f"[net]\nslaveid = {toml_edit.dump_value(GUIDE_SLAVEID)}\n"
    values, _ = do_set(schema, text, "net", "slaveid", "0")
    assert values["slaveid"] == []


def test_slaveid_table_holds_eight_ranges(schema):
    text = MASTER
    for first in range(1, 81, 10):
        values, text = do_set(schema, text, "net", "slaveid", str(first), str(first + 5), "0",
                              "0", "10.0.0.1")
    assert len(values["slaveid"]) == 8
    with pytest.raises(ConfigError, match="net.slaveid: .*8 ranges"):
        do_set(schema, text, "net", "slaveid", "100", "101", "0", "0", "10.0.0.1")


@pytest.mark.parametrize("words", [
    ("1", "8", "1", "0"),
    ("0x1", "8", "1", "0", "10.0.0.1"),
    ("248", "250", "1", "0", "10.0.0.1"),
    ("8", "1", "1", "0", "10.0.0.1"),
    ("1", "8", "250", "0", "10.0.0.1"),
    ("1", "8", "1", "2", "10.0.0.1"),
    ("1", "8", "1", "0", "host"),
    ("1", "8", "1", "1", "10.0.0.250"),
])
def test_slaveid_entry_refuses(schema, words):
    """The reasons are master mode's own (mbgw.config.slaveid); here: named and refused."""
    with pytest.raises(ConfigError, match=r"^net\.slaveid: slaveid '"):
        do_set(schema, MASTER, "net", "slaveid", *words)


def test_slaveid_new_range_overlapping_another_is_refused(schema):
    text = MASTER + f"[net]\nslaveid = {toml_edit.dump_value(GUIDE_SLAVEID)}\n"
    with pytest.raises(ConfigError, match="^net.slaveid: .*overlap"):
        do_set(schema, text, "net", "slaveid", "5", "12", "0", "0", "10.0.0.1")


def test_changing_the_mode_clears_authip_and_slaveid(schema):
    text = '[serial]\ndevice = "/dev/ttyS1"\n[net]\nslaveid = 5\nauthip = ["192.0.2.1"]\n' \
           'mdbport = 1502\n'
    values, text = do_set(schema, text, "serial", "mode", "master")
    assert "slaveid" not in values and "authip" not in values
    assert values["mdbport"] == 1502
    values, text = do_set(schema, text, "net", "slaveid", *GUIDE_SLAVEID[0].split())
    values, text = do_set(schema, text, "serial", "mode", "master")     # no change: kept
    assert values["slaveid"] == GUIDE_SLAVEID[:1]
    values, text = do_set(schema, text, "serial", "mode", "slave")
    assert "slaveid" not in values
    assert "# slaveid = 0" in text            # back to the commented slave-mode default


# --- text edits keep comments ---------------------------------------------------------------

HAND_WRITTEN = """\
# our line to the boiler room
[serial]
device = "/dev/ttyUSB1"   # the FTDI one
stout = 600 # ms: slow meters
# baudrate = 9600

[net]
authip = [
    "192.0.2.1",  # SCADA
    "192.0.2.2",
]
# end of net
"""


def test_edit_changes_a_value_in_place_keeping_comments():
    text = toml_edit.set_line(HAND_WRITTEN, "serial", "stout", "stout = 700")
    assert "stout = 700  # ms: slow meters\n" in text
    assert text.replace("stout = 700  # ms: slow meters", "stout = 600 # ms: slow meters") \
        == HAND_WRITTEN


def test_edit_takes_up_a_commented_default():
    text = toml_edit.set_line(HAND_WRITTEN, "serial", "baudrate", "baudrate = 19200")
    assert "# baudrate" not in text and "\nbaudrate = 19200\n\n[net]" in text


def test_edit_replaces_a_multi_line_value():
    text = toml_edit.set_line(HAND_WRITTEN, "net", "authip", 'authip = ["192.0.2.9"]')
    assert tomllib.loads(text)["net"]["authip"] == ["192.0.2.9"]
    assert "SCADA" not in text and "# end of net" in text


def test_edit_adds_a_key_at_the_end_of_its_group_and_a_missing_group():
    text = toml_edit.set_line(HAND_WRITTEN, "net", "mdbport", "mdbport = 1502")
    assert '    "192.0.2.2",\n]\nmdbport = 1502\n# end of net\n' in text
    text = toml_edit.set_line(text, "general", "log-level", 'log-level = "debug"')
    assert text.endswith('# end of net\n\n[general]\nlog-level = "debug"\n')
    assert tomllib.loads(text)["general"] == {"log-level": "debug"}


def test_edit_removes_a_key_leaving_its_commented_default():
    text = toml_edit.set_line(HAND_WRITTEN, "serial", "stout", None, "# stout = 600")
    assert "\n# stout = 600\n" in text and "stout" not in tomllib.loads(text)["serial"]


@pytest.mark.parametrize("value", [True, 0, 65535, "8e1", 'a "quoted" \\ \x7f\t', [0, 0],
                                   ["192.0.2.1", "2001:db8::1"], [], 1.5])
def test_dump_value_round_trips(value):
    assert tomllib.loads(f"k = {toml_edit.dump_value(value)}")["k"] == value


# --- the atomic write --------------------------------------------------------------------------

def test_write_atomic_replaces_keeping_the_mode(tmp_path):
    path = write(tmp_path, "old\n")
    os.chmod(path, 0o640)
    toml_edit.write_atomic(path, "new\n")
    assert path.read_text() == "new\n"
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert os.listdir(tmp_path) == ["mbgw.toml"]


def test_write_atomic_new_file_is_world_readable(tmp_path):
    path = tmp_path / "etc" / "mbgw" / "new.toml"
    toml_edit.write_atomic(path, "x = 1\n")
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def test_write_atomic_failure_leaves_the_old_file(tmp_path, monkeypatch):
    path = write(tmp_path, "old\n")

    def fail(*_):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError):
        toml_edit.write_atomic(path, "new\n")
    assert path.read_text() == "old\n"
    assert os.listdir(tmp_path) == ["mbgw.toml"]


def test_write_atomic_refuses_what_is_not_a_regular_file(tmp_path):
    with pytest.raises(OSError, match="not a regular file"):
        toml_edit.write_atomic(os.devnull, "x = 1\n")
    (tmp_path / "dir.toml").mkdir()
    with pytest.raises(OSError, match="not a regular file"):
        toml_edit.write_atomic(tmp_path / "dir.toml", "x = 1\n")


# --- [table]: the exchange table's keys ------------------------------------------------------

@pytest.mark.parametrize("name", ["enabled", "direct", "units", "functions", "address", "port",
                                  "persist", "persist-interval"])
def test_table_keys_are_in_table(schema, name):
    assert schema.keys[name].group == "table"
    assert schema.label(name) == f"table.{name}"


def test_table_keys_modes(schema):
    assert set(schema.keys["direct"].params) == set(schema.keys["units"].params) == {"slave"}
    assert set(schema.keys["address"].params) == set(schema.keys["port"].params) == {"master"}
    for name in ("enabled", "functions", "persist", "persist-interval"):
        assert set(schema.keys[name].params) == {"slave", "master"}, name


def test_table_file_to_slave_config(tmp_path):
    from mbgw.cli.slave import slave_config
    path = write(tmp_path, '[serial]\ndevice = "/dev/ttyS3"\n[table]\nenabled = true\n'
                           'direct = false\nunits = "1,5,200-202"\nfunctions = "3, 4,16"\n'
                           'persist = "/var/lib/mbgw/table"\npersist-interval = 30\n')
    options = cf.load_options(main, path)
    options.pop("mode")
    table = slave_config(**options).table
    assert table.enabled and not table.direct
    assert table.units == (1, 5, 200, 201, 202)
    assert table.functions == (3, 4, 16)
    assert table.persist == "/var/lib/mbgw/table" and table.persist_interval_s == 30


def test_table_file_to_master_config(tmp_path):
    from mbgw.cli.master import master_config
    path = write(tmp_path, '[serial]\nmode = "master"\ndevice = "/dev/ttyS3"\n'
                           '[net]\nslaveid = ["1 8 1 0 192.168.0.30"]\n'
                           '[table]\nenabled = true\naddress = 9\nport = 1502\n')
    options = cf.load_options(main, path)
    options.pop("mode")
    table = master_config(**options).table
    assert (table.enabled, table.address, table.port) == (True, 9, 1502)
    assert table.functions == (1, 2, 3, 4, 5, 6, 7, 15, 16, 23)     # the default: all


def test_table_defaults_when_the_file_has_no_table(tmp_path):
    from mbgw.cli.slave import slave_config
    options = cf.load_options(main, write(tmp_path, '[serial]\ndevice = "/dev/ttyS3"\n'))
    options.pop("mode")
    assert slave_config(**options).table == TableConfig()


@pytest.mark.parametrize("text, expected", [
    ("[table]\nenabled = 'yes'", "table.enabled: expected true or false"),
    ("[table]\nunits = '0-3'", "table.units: table-units '0-3': 0 out of range 1..255"),
    ("[table]\nunits = '1,x'", "table.units: table-units '1,x': 'x' is not a number or a range"),
    ("[table]\nunits = '9-3'", "table.units: table-units '9-3': range 9-3 runs backwards"),
    ("[table]\nunits = ''", "table.units: table-units '': empty"),
    ("[table]\nunits = [247, 248]", "table.units: expected a single value, not a list"),
    ("[table]\nfunctions = '3,8'", "table.functions: table-functions '3,8': 8: the table "
                                   "answers only 1, 2, 3, 4, 5, 6, 7, 15, 16, 23"),
    ("[table]\npersist = ''", "table.persist: table-persist: empty"),
    ("[table]\npersist-interval = 0", "table.persist-interval: 0 is not in the range"),
    ("[serial]\nmode = 'master'\n[table]\naddress = 248",
     "table.address: 248 is not in the range 0<=x<=247"),
    ("[serial]\nmode = 'master'\n[table]\nport = 0", "table.port: 0 is not in the range"),
    ("[table]\nunit = '1'", "table.unit: unknown key; did you mean table.units?"),
    ("[net]\nunits = '1'", "net.units: belongs in [table] (table.units)"),
    ("[table]\nmdbport = 502", "table.mdbport: belongs in [net] (net.mdbport)"),
])
def test_bad_table_values_name_the_key_and_the_reason(schema, tmp_path, text, expected):
    assert expected in problems(schema, tmp_path, text)


def test_master_table_address_inside_a_slaveid_range_names_both(schema, tmp_path):
    text = ('[serial]\nmode = "master"\n[net]\nslaveid = ["1 8 1 0 192.168.0.30"]\n'
            '[table]\nenabled = true\naddress = 5\n')
    assert ("table.address: serial address 5 is in the slaveid range 1..8 "
            "(1 8 1 0 192.168.0.30)") in problems(schema, tmp_path, text)
    # the table off: its address reaches nobody, the range serves 5
    cf.check(schema, "f", tomllib.loads(text.replace("enabled = true", "enabled = false")))


@pytest.mark.parametrize("words, value", [
    (("table", "enabled", "on"), True),
    (("table", "direct", "off"), False),
    (("table", "units", "247-254"), "247-254"),
    (("table", "units", "1,5", "200-210"), "1,5,200-210"),
    (("table", "functions", "3", "4", "16"), "3,4,16"),
    (("table", "persist", "/var/lib/mbgw/table"), "/var/lib/mbgw/table"),
    (("table", "persist-interval", "60"), 60),
])
def test_set_table_takes_the_guides_words(schema, words, value):
    group, name, *rest = words
    values, text = do_set(schema, "", group, name, *rest)
    assert values[name] == value
    assert "[table]" in text


def test_set_table_address_in_master_mode(schema):
    values, _ = do_set(schema, '[serial]\nmode = "master"\n', "table", "address", "17")
    assert values["address"] == 17


@pytest.mark.parametrize("words, expected", [
    (("table", "units", "300"), "table.units: table-units '300': 300 out of range 1..255"),
    (("table", "functions", "8"), "table.functions: table-functions '8': 8: the table"),
    (("table", "enabled", "maybe"), "table.enabled: expected on or off"),
    (("table", "persist-interval", "0"), "table.persist-interval: 0 is not in the range"),
    (("net", "units", "1"), "net.units: belongs in [table]: mbgw config set table units"),
])
def test_set_table_refuses_what_the_command_line_refuses(schema, words, expected):
    group, name, *rest = words
    with pytest.raises(ConfigError) as caught:
        do_set(schema, "", group, name, *rest)
    assert expected in str(caught.value)


@pytest.mark.parametrize("text, numbers", [
    ("247-254", tuple(range(247, 255))), ("1,5,200-202", (1, 5, 200, 201, 202)),
    ("5 1  3", (1, 3, 5)), ("3,3,1-3", (1, 2, 3)),
])
def test_number_lists(text, numbers):
    assert parse_number_list("table-units", text, 1, 255) == numbers
    assert parse_number_list("table-units", number_list_text(numbers), 1, 255) == numbers
