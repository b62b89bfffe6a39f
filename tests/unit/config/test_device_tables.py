"""[[device]] in the configuration file: each unit's own timing on a line in slave mode
(issue 29), reaching the daemon's settings, and every refusal naming its table and key
(check-config exit 78)."""

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.config.lines import DeviceConfig
from tests.unit.config.config_files import built, refusal

SERIAL = '[serial]\ndevice = "/dev/ttyUSB0"\nstout = 1000\n'
METERS = '[[line]]\nname = "meters"\ndevice = "/dev/ttyUSB1"\n'
PANEL = '[[line]]\nname = "panel"\ndevice = "/dev/ttyUSB2"\nmode = "master"\n'
ROUTES = ('[[route]]\nunits = "1-31"\nline = "serial"\n'
          '[[route]]\nunits = "32-63"\nline = "meters"\noffset = -31\n')
FAST = '[[device]]\nunit = 5\nstout = 50\n'


def test_devices_reach_the_slave_config(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + METERS + ROUTES + FAST
                + '[[device]]\nline = "meters"\nunit = 2\nretries = 3\npause = 20\n'
                  'down-after = 0\nprobe-interval = 200\n')
    assert cfg.devices == (
        DeviceConfig(1, 5, "serial", stout_ms=50),
        DeviceConfig(2, 2, "meters", retries=3, pause_ms=20, down_after=0,
                     probe_interval_ms=200))


def test_a_device_on_the_implicit_route_of_line_serial(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + FAST)
    assert [d.unit for d in cfg.devices] == [5]


def test_a_master_mode_daemon_takes_devices_of_its_slave_mode_lines(schema, tmp_path):
    text = ('[serial]\nmode = "master"\ndevice = "/dev/ttyUSB0"\n' + METERS
            + '[[route]]\nfrom = "serial"\nunits = "1-10"\nline = "meters"\n'
            + '[[device]]\nline = "meters"\nunit = 4\nstout = 30\n')
    assert [(d.line, d.unit) for d in built(schema, tmp_path, text).devices] == [("meters", 4)]


@pytest.mark.parametrize("text, expected", [
    (SERIAL + FAST + FAST, "device 2.unit: unit 5 of line serial has device 1 already"),
    (SERIAL + '[[device]]\nline = "nope"\nunit = 3\n', "device 1.line 'nope': no such line"),
    (SERIAL + PANEL + '[[route]]\nunits = "1-9"\nline = "serial"\n'
     + '[[device]]\nline = "panel"\nunit = 3\n',
     "device 1.line 'panel': the line is in master mode"),
    (SERIAL + '[[device]]\nunit = 3\nstuot = 30\n',
     "device 1.stuot: unknown key (keys: line, unit, stout, retries, pause, down-after, "
     "probe-interval); did you mean stout?"),
    (SERIAL + '[[device]]\nunit = 3\nstout = 0\n', "device 1.stout: 0 out of range 1..65535"),
    (SERIAL + '[[device]]\nunit = 3\nretries = 70000\n',
     "device 1.retries: 70000 out of range 0..65535"),
    (SERIAL + '[[device]]\nunit = 3\ndown-after = 101\n',
     "device 1.down-after: 101 out of range 0..100"),
    (SERIAL + '[[device]]\nunit = 3\nprobe-interval = 99\n',
     "device 1.probe-interval: 99 out of range 100..65535"),
    (SERIAL + '[[device]]\nunit = 3\npause = -1\n', "device 1.pause: -1 out of range 0..65535"),
    (SERIAL + '[[device]]\nunit = 248\n', "device 1.unit: 248 out of range 1..247"),
    (SERIAL + '[[device]]\nstout = 30\n', "device 1.unit: missing"),
    (SERIAL + '[[device]]\nunit = "5"\n', "device 1.unit: expected a serial address"),
    (SERIAL + METERS + ROUTES + '[[device]]\nline = "meters"\nunit = 40\n',
     "device 1.unit: no route reaches unit 40 of line meters"),
    (SERIAL + '[[route]]\nunits = "1-10"\nline = "serial"\n[[device]]\nunit = 30\n',
     "device 1.unit: no route reaches unit 30 of line serial"),
])
def test_check_config_refuses_naming_the_device_and_key(tmp_path, text, expected):
    assert expected in refusal(tmp_path, text)


def test_the_transparent_command_refuses_devices(tmp_path):
    text = '[serial]\nmode = "transparent"\ndevice = "/dev/ttyUSB0"\n' + FAST
    assert "device: [[device]] tables are for slave and master modes" in refusal(tmp_path, text)


def test_config_show_lists_the_device_tables(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(SERIAL + FAST + '[[device]]\nunit = 6\nretries = 2\npause = 0\n')
    result = CliRunner().invoke(main, ["config", "show", "device", "--config", str(path)],
                                prog_name="mbgw")
    assert result.exit_code == 0, result.output
    assert result.output == ('[[device]]\nline = "serial"\nunit = 5\nstout = 50\n\n'
                             '[[device]]\nline = "serial"\nunit = 6\nretries = 2\n')
