"""The command line (mbgw.cli.main) through click's CliRunner.  Only result.output and
result.exit_code are used: the rest of the runner's API differs between click 8.1 and 8.2+."""
import re

import click
import pytest
from click.testing import CliRunner

from mbgw import __version__
from mbgw.cli import main

DEVICE = ["--device", "/nonexistent/tty"]


def _slave(*args: str):
    return CliRunner().invoke(main, ["slave", *args])


def _usage_error(result, option: str, value: str) -> None:
    assert result.exit_code == 2, result.output
    assert option in result.output
    assert value in result.output


@pytest.mark.parametrize("option, value", [
    ("--stout", "0"),
    ("--stout", "70000"),
    ("--stout", "-1"),
    ("--format", "9x1"),
    ("--format", "8n3"),
    ("--format", "8x1"),
    ("--protocol", "tcp"),
    ("--interface", "rs999"),
    ("--interface", "rs232 echo"),
    ("--silence", "65536"),
    ("--ascii-timeout", "0"),
    ("--baudrate", "0"),
    ("--baudrate", "49"),
    ("--baudrate", "4000001"),
    ("--baudrate", "fast"),
    ("--slaveid", "248"),
    ("--slaveid", "-1"),
    ("--authip", "notanip"),
    ("--authip", "192.0.2.0/24"),
    ("--mdbport", "0"),
    ("--mdbport", "65536"),
    ("--max-connections", "0"),
    ("--max-connections-per-ip", "-1"),
    ("--max-connections-per-ip", "1001"),
    ("--retries", "65536"),
    ("--turnaround", "65536"),
    ("--late-window", "-1"),
    ("--late-window", "65536"),
    ("--down-after", "-1"),
    ("--down-after", "101"),
    ("--probe-interval", "99"),
    ("--probe-interval", "65536"),
    ("--log-level", "loud"),
])
def test_bad_value_is_a_usage_error_naming_option_and_value(option, value):
    _usage_error(_slave(*DEVICE, option, value), option, value)


def test_rtsdelays_out_of_range():
    _usage_error(_slave(*DEVICE, "--rtsdelays", "0", "256"), "--rtsdelays", "256")


def test_nine_authip_values_are_one_too_many():
    args = []
    for i in range(1, 10):
        args += ["--authip", f"192.0.2.{i}"]
    result = _slave(*DEVICE, *args)
    _usage_error(result, "--authip", "9")
    assert "8" in result.output


def test_device_is_required():
    result = _slave()
    assert result.exit_code == 2
    assert "--device" in result.output


def test_version():
    result = CliRunner().invoke(main, ["--version"])
    assert result.exit_code == 0
    assert "mbgw" in result.output
    assert __version__ in result.output


def _help_entries(output: str) -> dict[str, str]:
    """Option -> its help text (continuation lines joined, words re-joined where click wrapped
    them at a hyphen), from click's two-column option list."""
    entries: dict[str, list[str]] = {}
    current = None
    for line in output.splitlines():
        if re.match(r"^  -", line):
            current = line.split()[0]
            entries[current] = [line]
        elif current is not None and line.startswith("   "):
            entries[current].append(line)
        else:
            current = None
    return {option: re.sub(r"\s+", " ", re.sub(r"-\n\s+", "-", "\n".join(lines)))
            for option, lines in entries.items()}


# The ACKSYS commands' defaults (seeds/000, "set serial stout 600", "set net mdbport 502",
# exception off) and the rest as documented in README.md.
HELP_DEFAULTS = {
    "--protocol": "default: rtu",
    "--baudrate": "default: 9600",
    "--format": "default: 8n1",
    "--interface": "default: rs232",
    "--rtsdelays": "default: 0, 0",
    "--stout": "default: 600",
    "--silence": "default: 0",
    "--ascii-timeout": "default: 1000",
    "--slaveid": "default: 0",
    "--exception": "default: no-exception",
    "--mdbport": "default: 502",
    "--bind": "default: all",
    "--max-connections": "default: 5",
    "--max-connections-per-ip": "default: 0",
    "--retries": "default: 0",
    "--turnaround": "default: 100",
    "--late-window": "default: stout",
    "--down-after": "default: 3",
    "--probe-interval": "default: 5000",
    "--log-level": "default: info",
}


def test_slave_help_lists_every_option_with_its_default():
    result = _slave("--help")
    assert result.exit_code == 0
    entries = _help_entries(result.output)
    for option, default in HELP_DEFAULTS.items():
        assert option in entries, f"{option} missing from --help"
        assert default in entries[option], f"{option}: {entries[option]!r}"
    assert "required" in entries["--device"]
    assert "--authip" in entries
    assert "--nocheck" in entries
    assert "8" in entries["--authip"]


def test_device_that_cannot_be_opened_exits_1_with_one_line_naming_it():
    # there, but no tty (a device that is not there yet is waited for)
    result = _slave("--device", "/dev/null")
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    assert "/dev/null" in lines[0]
    assert "Traceback" not in result.output


@pytest.mark.parametrize("path, reason", [
    ("/etc/hostname", "a regular file, not a serial device"),
    ("/etc", "a directory, not a serial device"),
    ("/etc/hostname/tty0", "/etc/hostname is not a directory"),
    ("ttyUSB0", "not an absolute path"),
])
def test_a_path_that_can_never_be_a_serial_device_is_a_usage_error(path, reason):
    _usage_error(_slave("--device", path), "'--device'", reason)


def _command_paths(group: click.Group, path=()):
    """The words of every command and group under group, e.g. ("clients", "close")."""
    for name in group.list_commands(click.Context(group)):
        command = group.get_command(click.Context(group), name)
        yield (*path, name)
        if isinstance(command, click.Group):
            yield from _command_paths(command, (*path, name))


def test_every_command_takes_dash_h_for_help():
    paths = [(), *_command_paths(main)]
    assert ("clients", "close") in paths and ("config", "set") in paths
    for path in paths:
        short = CliRunner().invoke(main, [*path, "-h"])
        assert short.exit_code == 0, (path, short.output)
        assert short.output == CliRunner().invoke(main, [*path, "--help"]).output, path
        assert "-h, --help" in short.output, path


@pytest.mark.parametrize("command", [["status"], ["trace"], ["clients", "close", "1"],
                                     ["clients"], ["clients", "close", "--all"],
                                     ["clients", "close", "10.0.0.1:502"], ["stats"],
                                     ["stats", "--json"], ["stats", "reset"]])
def test_diagnostics_reach_a_service_instance_by_name(command):
    """-i NAME: the socket of mbgw@NAME (its RuntimeDirectory=mbgw/%i), like `run -i NAME`
    takes /etc/mbgw/NAME.toml; no daemon runs here, so the command names the path."""
    result = CliRunner().invoke(main, [*command, "-i", "ttyTEST9"])
    assert result.exit_code == 1, result.output
    assert "no mbgw daemon answers on /run/mbgw/ttyTEST9/mbgw.sock" in result.output
    assert CliRunner().invoke(main, [*command, "--instance", "../x"]).exit_code == 2
    both = CliRunner().invoke(main, [*command, "-i", "x", "--control", "/tmp/x.sock"])
    assert both.exit_code == 2 and "not both" in both.output
