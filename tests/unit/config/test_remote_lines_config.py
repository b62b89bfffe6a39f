"""`[[line]] connect` (issue 26): a remote line's URL, connect-delay and pause, its defaults
taken from [serial], and what a remote line refuses (a serial port's keys, another mode)."""
import pytest

from mbgw.config.line_file import parse_connect
from mbgw.config.lines import RemoteTarget
from mbgw.errors import ConfigError
from tests.unit.config.config_files import SERIAL, built, refusal

ROUTE = '[[route]]\nunits = "40-49"\nline = "inverter"\n'


def inverter(**keys) -> str:
    fields = {"name": '"inverter"', "connect": '"modbus-tcp://192.168.1.40:502"', **keys}
    return "[[line]]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items())


@pytest.mark.parametrize("text, target", [
    ("modbus-tcp://192.168.1.40:502", RemoteTarget("modbus-tcp", "192.168.1.40", 502)),
    ("modbus-tcp://inverter.lan", RemoteTarget("modbus-tcp", "inverter.lan", 502)),
    ("rtu-over-tcp://10.0.0.5:4001", RemoteTarget("rtu-over-tcp", "10.0.0.5", 4001)),
    ("ascii-over-tcp://[fd00::5]:4001", RemoteTarget("ascii-over-tcp", "fd00::5", 4001)),
    ("rtu-over-udp://10.0.0.6:4002", RemoteTarget("rtu-over-udp", "10.0.0.6", 4002)),
    ("modbus-udp://10.0.0.7", RemoteTarget("modbus-udp", "10.0.0.7", 502)),
])
def test_connect_names_the_kind_host_and_port(text, target):
    assert parse_connect("line x.connect", text) == target
    assert parse_connect("line x.connect", target.url) == target


@pytest.mark.parametrize("text, reason", [
    ("tcp://10.0.0.5:502", "expected KIND://HOST:PORT"),
    ("10.0.0.5:502", "expected KIND://HOST:PORT"),
    ("rtu-over-tcp://10.0.0.5", "give the port"),
    ("modbus-tcp://10.0.0.5:70000", "is not 1..65535"),
    ("modbus-tcp://:502", "no host"),
])
def test_a_bad_connect_is_refused_saying_why(text, reason):
    with pytest.raises(ConfigError, match=reason):
        parse_connect("line x.connect", text)


def test_a_remote_line_takes_its_timing_from_serial_and_its_own_keys(schema, tmp_path):
    text = SERIAL + "stout = 700\nretries = 2\ndown-after = 5\n" + \
        inverter(**{"connect-delay": 1500, "pause": 20, "retries": 1}) + ROUTE
    cfg = built(schema, tmp_path, text)
    line = cfg.lines[0]
    assert line.remote == RemoteTarget("modbus-tcp", "192.168.1.40", 502)
    assert line.serial.device == "modbus-tcp://192.168.1.40:502"
    assert (line.serial.stout_ms, line.retries, line.demotion.down_after) == (700, 1, 5)
    assert (line.connect_delay_ms, line.serial.interframe_ms) == (1500, 20)
    assert line.is_target


def test_ascii_over_tcp_frames_as_ascii(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + inverter(
        connect='"ascii-over-tcp://10.0.0.5:4001"') + ROUTE)
    assert cfg.lines[0].serial.protocol == "ascii"


@pytest.mark.parametrize("keys, reason", [
    ({"baudrate": 9600}, "line inverter.baudrate: a serial port's key"),
    ({"device": '"/dev/ttyUSB1"'}, "line inverter.device: a serial port's key"),
    ({"mode": '"master"'}, "line inverter.connect: a remote line is a target"),
    ({"pause": -1}, "line inverter.pause: -1 out of range 0..65535"),
    ({"connect-delay": '"1s"'}, "line inverter.connect-delay: expected an integer (ms)"),
    ({"connect": '"serial:///dev/ttyUSB1"'}, "line inverter.connect: 'serial:///dev/ttyUSB1'"),
])
def test_a_remote_line_refuses_what_is_not_for_it(tmp_path, keys, reason):
    assert reason in refusal(tmp_path, SERIAL + inverter(**keys) + ROUTE)


def test_pause_and_connect_delay_are_for_remote_lines_only(tmp_path):
    text = SERIAL + '[[line]]\nname = "meters"\ndevice = "/dev/ttyUSB1"\npause = 5\n'
    assert "line meters.pause: only with connect" in refusal(tmp_path, text)


def test_two_lines_to_one_device_are_refused(tmp_path):
    text = SERIAL + inverter() + inverter(name='"second"') + ROUTE
    assert "line second.device modbus-tcp://192.168.1.40:502: line inverter uses it" in \
        refusal(tmp_path, text)
