"""[[line]] and [[route]] in the configuration file: parsing into LineConfig/RouteConfig, every
refusal naming its line or route and key (check-config exit 78, `mbgw run` the same), the
implicit routes of both modes, and files without them unchanged."""

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.config.lines import PRIMARY_LINE, TCP_FACE
from mbgw.config.route_plan import implicit_routes, route_map
from tests.unit.config.config_files import SERIAL, built, check_config, refusal, settings_of

METERS = '[[line]]\nname = "meters"\ndevice = "/dev/ttyUSB1"\nbaudrate = 9600\n'
PANEL = '[[line]]\nname = "panel"\ndevice = "/dev/ttyUSB2"\nmode = "master"\n'
EXAMPLE = (SERIAL + '[table]\nenabled = true\nunits = "247-254"\n' + METERS + PANEL
           + '[[route]]\nunits = "1-31"\nline = "serial"\n'
           + '[[route]]\nunits = "32-63"\nline = "meters"\noffset = -31\n'
           + '[[route]]\nfrom = "panel"\nunits = "1-10"\nline = "meters"\n')


# --- parsing ---------------------------------------------------------------------------------

def test_lines_and_routes_reach_the_slave_config(schema, tmp_path):
    cfg = built(schema, tmp_path, EXAMPLE)
    assert [(line.name, line.mode, line.serial.device, line.serial.baudrate)
            for line in cfg.lines] == [("meters", "slave", "/dev/ttyUSB1", 9600),
                                       ("panel", "master", "/dev/ttyUSB2", cfg.serial.baudrate)]
    assert cfg.serial.device == "/dev/ttyUSB0"          # [serial] stays line serial
    meters = cfg.lines[0]
    assert meters.serial.stout_ms == cfg.serial.stout_ms  # [serial]'s defaults
    assert (meters.retries, meters.demotion) == (cfg.retries, cfg.demotion)
    first, second, third = cfg.routes
    assert (first.index, first.units, first.line, first.face) == (1, tuple(range(1, 32)),
                                                                  PRIMARY_LINE, TCP_FACE)
    assert (second.line, second.offset, second.rewrite(32)) == ("meters", -31, 1)
    assert (third.face, third.line, third.units) == ("panel", "meters", tuple(range(1, 11)))


def test_every_serial_key_may_be_on_a_line(schema, tmp_path):
    text = SERIAL + ('[[line]]\nname = "m"\ndevice = "/dev/ttyUSB1"\nformat = "8e1"\n'
                     'protocol = "ascii"\ninterface = "rs485"\nstout = 700\nsilence = 5\n'
                     'retries = 2\ndown-after = 4\nprobe-interval = 2000\nrtsdelays = [1, 2]\n'
                     'ascii-timeout = 900\ninterframe-silence = 3\nturnaround = 150\n'
                     'late-window = 40\n')
    line = built(schema, tmp_path, text).lines[0]
    assert (line.serial.protocol, line.serial.stout_ms, line.serial.silence_ms,
            line.serial.rtsdelays, line.serial.ascii_timeout_ms, line.serial.interframe_ms) \
        == ("ascii", 700, 5, (1, 2), 900, 3)
    assert str(line.serial.format) == "8e1"
    assert (line.retries, line.demotion.down_after, line.demotion.probe_interval_ms,
            line.turnaround_ms, line.late_window_ms) == (2, 4, 2000, 150, 40)


def test_routes_to_servers_and_fixed_addresses(schema, tmp_path):
    text = SERIAL + ('[[route]]\nunits = "100-101"\nserver = "[::1]:1502"\n'
                     '[[route]]\nunits = "102"\nserver = "192.0.2.7"\naddress = 0\n')
    v6, v4 = built(schema, tmp_path, text).routes
    assert (v6.server, v6.target) == (("::1", 1502), "server [::1]:1502")
    assert (v4.server, v4.rewrite(102)) == (("192.0.2.7", 502), 0)


def test_old_files_are_unchanged(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + "[net]\nslaveid = 5\n")
    assert (cfg.lines, cfg.routes) == ((), ())
    assert "lines" not in settings_of(schema, tmp_path, SERIAL).default_map(schema, "slave")


def test_check_config_accepts_the_example(tmp_path):
    path, result = check_config(tmp_path, EXAMPLE)
    assert result.exit_code == 0, result.output
    assert result.output == f"{path}: ok (slave mode)\n"


# --- refusals --------------------------------------------------------------------------------

ROUTE_TO_SERIAL = '[[route]]\nunits = "1-10"\nline = "serial"\n'


@pytest.mark.parametrize("text, expected", [
    (SERIAL + '[[line]]\nname = "serial"\ndevice = "/dev/ttyUSB1"\n',
     "line serial.name: 'serial' is [serial]'s name, reserved"),
    (SERIAL + '[[line]]\nname = "Meters"\ndevice = "/dev/ttyUSB1"\n',
     "line 1.name: 'Meters': expected 1 to 32 of a-z, 0-9 and -"),
    (SERIAL + '[[line]]\ndevice = "/dev/ttyUSB1"\n',
     "line 1.name: missing; every [[line]] has a name"),
    (SERIAL + '[[line]]\nname = "m"\n', "line m.device: missing; every line needs its device"),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/dev/ttyUSB1"\nbaudrate = 3\n',
     "line m.baudrate: 3 is not in the range"),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/dev/ttyUSB1"\nbaudrat = 9600\n',
     "line m.baudrat: unknown key; did you mean baudrate?"),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/dev/ttyUSB1"\nmode = "both"\n',
     "line m.mode: expected \"slave\""),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/dev/ttyUSB1"\nmode = "master"\nretries = 2\n',
     "line m.retries: applies to slave-mode lines only"),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/dev/ttyUSB1"\nmode = "master"\nstout = 2\n',
     "line m.stout: applies to slave-mode lines only"),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/dev/ttyUSB1"\ninterface = "rs232"\n'
     'rts = "flow"\n', "line m.rts: rts flow with cts ignore"),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/etc/passwd"\n',
     "line m.device: device /etc/passwd: a regular file, not a serial device"),
    (SERIAL + '[[line]]\nname = "m"\ndevice = "/dev/ttyUSB0"\n',
     "line m.device /dev/ttyUSB0: line serial uses it already"),
    (SERIAL + METERS + METERS.replace("USB1", "USB2"),
     "line meters.name: two lines are named 'meters'"),
    (SERIAL + '[[route]]\nunits = "1-300"\nline = "serial"\n',
     "route 1.units: '1-300': 300 out of range 1..255"),
    (SERIAL + '[[route]]\nline = "serial"\n', "route 1.units: missing"),
    (SERIAL + '[[route]]\nunits = "1"\nline = "serial"\nvia = "x"\n',
     "route 1.via: unknown key (keys: units, line, table, server, offset, address, from, "
     "tls, fingerprint, cache)"),
    (SERIAL + '[[route]]\nunits = "1"\nline = "nowhere"\n', "route 1.line 'nowhere': no such line"),
    (SERIAL + '[[route]]\nunits = "1"\n', "route 1: give one target"),
    (SERIAL + '[[route]]\nunits = "1"\nline = "serial"\ntable = true\n',
     "route 1: give one target: line = NAME, table = true or server = \"IP[:PORT]\" "
     "(got line and table)"),
    (SERIAL + ROUTE_TO_SERIAL + '[[route]]\nunits = "10-20"\nserver = "192.0.2.1"\n',
     "route 2.units: unit 10 is routed by route 1 already"),
    (SERIAL + '[table]\nenabled = true\n' + '[[route]]\nunits = "240-250"\nline = "serial"\n'
     'offset = -100\n', "route 1.units: unit 247 is routed by table.units already"),
    (SERIAL + ROUTE_TO_SERIAL.replace('"serial"\n', '"serial"\noffset = 3\naddress = 4\n'),
     "route 1.offset: offset and address exclude each other"),
    (SERIAL + ROUTE_TO_SERIAL.replace('"serial"\n', '"serial"\noffset = -5\n'),
     "route 1.offset: unit 1 becomes -4, outside 1..247"),
    (SERIAL + ROUTE_TO_SERIAL.replace('"serial"\n', '"serial"\naddress = 248\n'),
     "route 1.address: unit 1 becomes 248, outside 1..247"),
    (SERIAL + '[[route]]\nunits = "250"\nline = "serial"\n',
     "route 1.units: unit 250 is outside 1..247, the target's addresses; give offset or address"),
    (SERIAL + '[[route]]\nunits = "200"\nserver = "192.0.2.1"\noffset = 100\n',
     "route 1.offset: unit 200 becomes 300, outside 0..255"),
    (SERIAL + '[[route]]\nunits = "1"\nserver = "192.0.2.1:99999"\n',
     "route 1.server: '192.0.2.1:99999': port '99999' out of range 1..65535"),
    (SERIAL + ROUTE_TO_SERIAL.replace("units", 'from = "serial"\nunits'),
     "route 1.from 'serial': the line is in slave mode; from names a line in master mode"),
    (SERIAL + PANEL + '[[route]]\nunits = "1"\nline = "panel"\n',
     "route 1.line 'panel': the line is in master mode"),
    (SERIAL + ROUTE_TO_SERIAL.replace("units", 'from = "nope"\nunits'),
     "route 1.from 'nope': no such line"),
    (SERIAL + '[table]\nenabled = true\nunits = "250"\n[[route]]\nunits = "1"\ntable = true\n',
     "route 1.table: table.units routes units to the table already; both at once is an "
     "overlap"),
    (SERIAL + '[[route]]\nunits = "1"\ntable = true\n',
     "route 1.table: the table is off (table.enabled = false)"),
    ('[serial]\nmode = "transparent"\ndevice = "/dev/ttyUSB0"\n' + METERS,
     "line: [[line]] tables are for slave and master modes; transparent mode bridges [serial]"),
    ('line = "meters"\n' + SERIAL, "line: expected [[line]] tables"),
])
def test_check_config_refuses_naming_the_line_or_route(tmp_path, text, expected):
    assert expected in refusal(tmp_path, text)


def test_master_mode_line_serial_is_a_face(schema, tmp_path):
    text = ('[serial]\nmode = "master"\ndevice = "/dev/ttyUSB0"\n' + METERS
            + '[[route]]\nfrom = "serial"\nunits = "1-31"\nline = "meters"\n')
    cfg = built(schema, tmp_path, text)
    assert cfg.routes[0].face == PRIMARY_LINE
    assert "route 1.line 'serial': the line is in master mode" in refusal(
        tmp_path, text.replace('line = "meters"', 'line = "serial"'))


def test_a_master_mode_daemon_takes_routes_from_the_tcp_face(schema, tmp_path):
    """A route without `from` in a master-mode daemon is its Modbus TCP face's (it listens on
    mdbport); a face whose port the table's server has is refused by check-config and run
    alike, naming the key."""
    text = ('[serial]\nmode = "master"\ndevice = "/dev/ttyUSB0"\n' + METERS
            + '[[route]]\nfrom = "serial"\nunits = "1-31"\nline = "meters"\n'
            + '[[route]]\nunits = "32-63"\nline = "meters"\noffset = -31\n')
    cfg = built(schema, tmp_path, text)
    assert [r.face for r in cfg.routes] == [PRIMARY_LINE, TCP_FACE]
    clash = text.replace('[serial]\n', '[table]\nenabled = true\n[serial]\n')
    expected = ("net.mdbport 502: route 2 makes it the Modbus TCP face's port, and the "
                "table's server listens on it (table.port)")
    assert expected in refusal(tmp_path, clash)
    result = CliRunner().invoke(main, ["run", "--config", str(tmp_path / "mbgw.toml")],
                                prog_name="mbgw")
    assert result.exit_code == 78, result.output
    assert expected in result.output


def test_run_refuses_what_check_config_refuses(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(SERIAL + '[[route]]\nunits = "1"\nline = "nowhere"\n')
    result = CliRunner().invoke(main, ["run", "--config", str(path)], prog_name="mbgw")
    assert result.exit_code == 78, result.output
    assert "route 1.line 'nowhere': no such line" in result.output


def test_the_transparent_command_refuses_a_file_with_lines(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(SERIAL + METERS)
    result = CliRunner().invoke(main, ["transparent", "--config", str(path)], prog_name="mbgw")
    assert result.exit_code == 78, result.output
    assert "line: [[line]] and [[route]] tables are for slave and master modes; transparent " \
           "mode bridges [serial] only" in result.output


# --- implicit routes -------------------------------------------------------------------------

def test_slave_mode_implicit_routes_are_todays_routing(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + '[table]\nenabled = true\nunits = "250-254"\n')
    table, serial = implicit_routes(cfg)
    assert (table.table, table.units, table.implicit) == (True, tuple(range(250, 255)), True)
    assert serial.line == PRIMARY_LINE and serial.address is None
    assert set(serial.units) == set(range(256)) - set(range(250, 255))
    forced = built(schema, tmp_path, SERIAL + "[net]\nslaveid = 7\n")
    (only,) = implicit_routes(forced)
    assert (only.units, only.rewrite(3), only.rewrite(200)) == (tuple(range(256)), 7, 7)


def test_explicit_routes_keep_only_the_table_route(schema, tmp_path):
    cfg = built(schema, tmp_path, EXAMPLE)
    (table,) = implicit_routes(cfg)
    assert table.units == tuple(range(247, 255)) and table.label == "table.units"
    units = route_map(cfg).units(TCP_FACE)
    assert units[1] is cfg.routes[0] and units[40] is cfg.routes[1]
    assert units[250] == table and units[100] is None
    assert route_map(cfg).units("panel")[3] is cfg.routes[2]


def test_a_table_route_replaces_table_units(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + '[table]\nenabled = true\n'
                '[[route]]\nunits = "1-5"\ntable = true\n')
    assert implicit_routes(cfg) == ()


def test_routes_from_a_panel_leave_the_tcp_face_as_today(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + PANEL + '[[route]]\nfrom = "panel"\nunits = "1"\n'
                'line = "serial"\n')
    (serial,) = implicit_routes(cfg)
    assert (serial.face, serial.line, len(serial.units)) == (TCP_FACE, PRIMARY_LINE, 256)


def test_master_mode_slaveid_ranges_are_the_serial_faces_routes(schema, tmp_path):
    text = ('[serial]\nmode = "master"\ndevice = "/dev/ttyUSB0"\n[net]\nmdbport = 1502\n'
            'slaveid = ["1 8 1 0 192.168.0.30", "9 10 0 1 192.168.20.0", '
            '"17 24 31 0 192.168.50.1"]\n')
    cfg = built(schema, tmp_path, text)
    routes = implicit_routes(cfg)
    assert all(r.face == PRIMARY_LINE and r.implicit and r.label == "net.slaveid"
               for r in routes)
    fixed, first, second, shifted = routes
    assert (fixed.units, fixed.server, fixed.rewrite(3)) == (tuple(range(1, 9)),
                                                             ("192.168.0.30", 1502), 3)
    assert (first.units, first.server, first.rewrite(9)) == ((9,), ("192.168.20.0", 1502), 0xFF)
    assert (second.units, second.server) == ((10,), ("192.168.20.1", 1502))
    assert shifted.rewrite(17) == 31 and shifted.rewrite(24) == 38
    explicit = built(schema, tmp_path, text + METERS
                     + '[[route]]\nfrom = "serial"\nunits = "30"\nline = "meters"\n')
    assert implicit_routes(explicit) == ()


def test_config_show_lists_lines_routes_and_the_implicit_ones(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(EXAMPLE)
    result = CliRunner().invoke(main, ["config", "show", "route", "--config", str(path)],
                                prog_name="mbgw")
    assert result.exit_code == 0, result.output
    assert '[[route]]\nunits = "32-63"\nline = "meters"\noffset = -31\n' in result.output
    assert "# implicit (table.units): units 247-254 -> table" in result.output
    shown = CliRunner().invoke(main, ["config", "show", "line", "meters", "--config",
                                      str(path)], prog_name="mbgw")
    assert shown.output.strip() == ('[[line]]\nname = "meters"\nmode = "slave"\n'
                                    'device = "/dev/ttyUSB1"\nbaudrate = 9600')


# --- the documented examples -----------------------------------------------------------------

def _toml_after(text: str, opening: str, closing: str) -> str:
    start = text.index(opening)
    return text[start:text.index(closing, start)]


def test_the_readme_and_man_page_examples_pass_check_config(tmp_path):
    from tests.harness import CHECKOUT
    readme = (CHECKOUT / "README.md").read_text()
    example = _toml_after(readme, "# /tmp/lines.toml\n", "```")
    assert 'units = "32-63"' in example
    path, result = check_config(tmp_path, example)
    assert result.exit_code == 0, result.output
    page = (CHECKOUT / "docs" / "mbgw.toml.5").read_text()
    section = page[page.index('.SH "LINES AND ROUTES"'):page.index(".SH SCENARIOS")]
    example = _toml_after(section, ".nf\n", ".fi\n").removeprefix(".nf\n").replace("\\-", "-")
    path, result = check_config(tmp_path, example)
    assert result.exit_code == 0, result.output


def test_the_readme_inverter_example_needs_no_serial(tmp_path):
    from tests.harness import CHECKOUT
    readme = (CHECKOUT / "README.md").read_text()
    example = _toml_after(readme, "# /tmp/inverter.toml", "```")
    assert "[serial]" not in example.splitlines()
    path, result = check_config(tmp_path, example)
    assert result.exit_code == 0, result.output


# --- [serial] left out -----------------------------------------------------------------------

def test_without_serial_there_is_no_line_serial_and_only_the_files_routes(schema, tmp_path):
    cfg = built(schema, tmp_path, METERS + '[[route]]\nunits = "1-31"\nline = "meters"\n')
    assert not cfg.serial_line
    assert [r.target for r in route_map(cfg).routes] == ["line meters"]
    with_table = built(schema, tmp_path, METERS + '[table]\nenabled = true\nunits = "250"\n'
                       '[[route]]\nunits = "1-31"\nline = "meters"\n')
    assert [(r.target, r.implicit) for r in route_map(with_table).routes] == \
        [("table", True), ("line meters", False)]
    assert built(schema, tmp_path, EXAMPLE).serial_line


def test_a_serial_group_without_a_device_only_gives_the_lines_defaults(schema, tmp_path):
    cfg = built(schema, tmp_path, '[serial]\nstout = 900\n[[line]]\nname = "inverter"\n'
                'connect = "modbus-tcp://127.0.0.1:5020"\n'
                '[[route]]\nunits = "1"\nline = "inverter"\n')
    assert not cfg.serial_line
    assert [(line.name, line.serial.stout_ms) for line in cfg.lines] == [("inverter", 900)]


@pytest.mark.parametrize("text, problem", [
    (METERS, "serial.device: missing, so line serial does not run and no unit reaches a line"),
    (METERS + '[net]\nslaveid = 5\n[[route]]\nunits = "1"\nline = "meters"\n',
     "net.slaveid 5: the address on line serial, and [serial] is left out"),
    (METERS + '[[route]]\nunits = "1"\nline = "serial"\n',
     "route 1.line 'serial': no such line"),
])
def test_without_serial_check_config_refuses(tmp_path, text, problem):
    assert problem in refusal(tmp_path, text)


def test_without_lines_serial_device_is_still_missing(tmp_path):
    assert refusal(tmp_path, "[net]\nmdbport = 1502\n").startswith("serial.device: missing")


def test_an_empty_device_on_the_command_line_is_refused(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(METERS + '[[route]]\nunits = "1"\nline = "meters"\n')
    result = CliRunner().invoke(main, ["slave", "--config", str(path), "--device", ""],
                                prog_name="mbgw")
    assert result.exit_code != 0
    assert "device: empty" in result.output


def test_the_gateway_unit_is_an_implicit_route_of_its_own(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + '[general]\ngateway-unit = 200\n[table]\n'
                'enabled = true\nunits = "250-254"\n')
    gateway, table, serial = implicit_routes(cfg)
    assert (gateway.gateway, gateway.units, gateway.target) == (True, (200,), "gateway")
    assert gateway.label == "general.gateway-unit"
    assert table.units == tuple(range(250, 255))
    assert set(serial.units) == set(range(256)) - {200, *range(250, 255)}
    off = built(schema, tmp_path, SERIAL)
    assert not any(r.gateway for r in implicit_routes(off))


@pytest.mark.parametrize("text, other", [
    ('[general]\ngateway-unit = 251\n[table]\nenabled = true\nunits = "250-254"\n',
     "table.units"),
    ('[general]\ngateway-unit = 40\n[[route]]\nunits = "32-63"\nline = "serial"\n',
     "route 1"),
])
def test_the_gateway_unit_is_refused_inside_a_route_or_the_tables_units(tmp_path, text,
                                                                         other):
    message = refusal(tmp_path, SERIAL + text)
    assert "general.gateway-unit" in message and other in message


MASTER_SERIAL = '[serial]\nmode = "master"\ndevice = "/dev/ttyUSB0"\n'


@pytest.mark.parametrize("text, other", [
    # a serial face's own route (slave mode's [[line]] in master mode)
    (SERIAL + METERS + PANEL + '[general]\ngateway-unit = 5\n[[route]]\nfrom = "panel"\n'
     'units = "1-10"\nline = "meters"\n', "route 1"),
    # master mode's line serial: a slaveid range, the table's address, a route of its own
    (MASTER_SERIAL + '[general]\ngateway-unit = 12\n[net]\nslaveid = ["10 20 1 0 '
     '192.168.1.5"]\n', "net.slaveid"),
    (MASTER_SERIAL + '[general]\ngateway-unit = 100\n[table]\nenabled = true\naddress = 100\n',
     "table.address"),
    (MASTER_SERIAL + METERS + '[general]\ngateway-unit = 3\n[[route]]\nfrom = "serial"\n'
     'units = "1-10"\nline = "meters"\n', "route 1"),
    # master mode's TCP face
    (MASTER_SERIAL + METERS + '[general]\ngateway-unit = 40\n[[route]]\nunits = "32-63"\n'
     'line = "meters"\n', "route 1"),
])
def test_the_gateway_unit_is_refused_inside_any_faces_routes(tmp_path, text, other):
    message = refusal(tmp_path, text)
    assert "general.gateway-unit" in message and other in message


def test_the_gateway_unit_is_a_route_of_every_face(schema, tmp_path):
    slave = built(schema, tmp_path, SERIAL + PANEL + '[general]\ngateway-unit = 200\n')
    assert sorted(r.face or "tcp" for r in implicit_routes(slave) if r.gateway) == \
        ["panel", "tcp"]
    master = built(schema, tmp_path, MASTER_SERIAL + PANEL + METERS +
                   '[general]\ngateway-unit = 200\n[[route]]\nunits = "1-10"\n'
                   'line = "meters"\n')
    assert sorted(r.face or "tcp" for r in implicit_routes(master) if r.gateway) == \
        ["panel", "serial", "tcp"]
    without_tcp_face = built(schema, tmp_path, MASTER_SERIAL + '[general]\ngateway-unit = 9\n')
    assert [(r.face, r.units) for r in implicit_routes(without_tcp_face) if r.gateway] == \
        [("serial", (9,))]
