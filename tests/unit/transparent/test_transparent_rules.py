"""Transparent mode's settings and configuration keys: `mbgw config set serial mode
transparent`, `mbgw run` reaching `mbgw transparent`, and the areas' bounds named by key."""
import socket
import tomllib

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.config.model import SerialConfig
from mbgw.config.transparent import TransparentConfig
from mbgw.errors import ConfigError
from tests.harness import free_port


def mbgw(*args):
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="mbgw")


def test_config_set_mode_transparent_and_run_reaches_it(tmp_path):
    path = tmp_path / "mbgw.toml"
    # raw-port, a port the test holds: only transparent mode listens there, after mdbport
    # (a free port, not 502) and before it opens the device, so `run` failing on it is
    # transparent mode's own exit
    with socket.socket() as held:
        held.bind(("0.0.0.0", 0))
        held.listen()
        port = held.getsockname()[1]
        for words in (("serial", "mode", "transparent"), ("serial", "device", "/dev/null"),
                      ("transparent", "eof", "crlf"), ("transparent", "raw-port", port),
                      ("net", "mdbport", free_port())):
            result = mbgw("config", "set", *words, "--config", path)
            assert result.exit_code == 0, result.output
        values = tomllib.loads(path.read_text())
        assert values["serial"]["mode"] == "transparent"
        assert values["transparent"] == {"eof": "crlf", "raw-port": port}
        assert "ok (transparent mode)" in mbgw("check-config", path).output
        result = mbgw("run", "--config", path)
        assert result.exit_code == 1, result.output
        assert f"raw-port {port}: cannot listen there" in result.output
    # another mdbport: the first run's listener lives on in its result's traceback
    assert mbgw("config", "set", "net", "mdbport", free_port(), "--config", path).exit_code == 0
    result = mbgw("run", "--config", path)
    assert result.exit_code == 1 and "cannot open /dev/null" in result.output


@pytest.mark.parametrize("settings, message", [
    ({"rx_address": 2047, "rx_size": 4}, "rx-address 2047: the area (registers 2047..2048)"),
    ({"tx_address": 4000, "tx_size": 250}, "tx-address 4000: the area"),
    ({"eof": "etx"}, "eof 'etx': expected one of"),
    ({"rx_size": 251}, "rx-size 251: out of range 1..250"),
])
def test_areas_and_values_out_of_bounds_name_the_key(settings, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        TransparentConfig(**settings)


def test_the_command_line_names_the_option():
    result = mbgw("transparent", "--device", "/dev/null", "--rx-address", "2000")
    assert result.exit_code == 2 and "rx-address 2000: the area" in result.output


def test_eof_timeout_zero_is_the_lines_end_of_frame_silence():
    # t3.5 at 9600 bit/s: 3.65 ms
    assert TransparentConfig().eof_timeout_for(SerialConfig("/dev/x", baudrate=9600)) == 4
    assert TransparentConfig().eof_timeout_for(SerialConfig("/dev/x", silence_ms=20)) == 20
    assert TransparentConfig(eof_timeout_ms=7).eof_timeout_for(SerialConfig("/dev/x")) == 7
