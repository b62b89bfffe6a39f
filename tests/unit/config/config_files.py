"""A configuration file written to tmp_path, then checked as `mbgw run` (built) or
`mbgw check-config` (refusal) checks it: what the config tests share."""
import tomllib

from click.testing import CliRunner

from mbgw.cli import checks, main
from mbgw.config import file as cf

SERIAL = '[serial]\ndevice = "/dev/ttyUSB0"\n'


def settings_of(schema, tmp_path, text: str) -> cf.Settings:
    path = tmp_path / "mbgw.toml"
    path.write_text(text)
    return cf.check(schema, path, tomllib.loads(text))


def built(schema, tmp_path, text: str):
    """The daemon's settings from the file text."""
    return checks.check_file(schema, settings_of(schema, tmp_path, text))


def check_config(tmp_path, text: str):
    """(the file's path, the result of `mbgw check-config` on it)."""
    path = tmp_path / "mbgw.toml"
    path.write_text(text)
    return path, CliRunner().invoke(main, ["check-config", str(path)], prog_name="mbgw")


def refusal(tmp_path, text: str) -> str:
    """What check-config says refusing the file (exit 78), after the file's name."""
    path, result = check_config(tmp_path, text)
    assert result.exit_code == 78, result.output
    return result.output.removeprefix(f"mbgw: {path}: ")
