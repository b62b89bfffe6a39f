"""[[monitor]] maps: each table's keys, and what check-config refuses across them."""
import pytest

from mbgw.config.monitor import MonitorMap, monitor_problems, parse_monitors
from tests.unit.config.test_lines_config import SERIAL, check_config, refusal

GOOD = {"line": "tap", "unit": 1, "function": 3, "address": 0, "quantity": 10, "table": 0}


def test_a_whole_map_parses() -> None:
    maps, problems = parse_monitors([GOOD])
    assert problems == []
    assert maps == (MonitorMap(1, "tap", 1, 3, 0, 10, 0),)


@pytest.mark.parametrize("change, problem", [
    ({"function": 5}, "monitor 1.function: 5 out of range 1..4"),
    ({"function": 0}, "monitor 1.function: 0 out of range 1..4"),
    ({"table": 0x7FFB}, "monitor 1.quantity: 10 registers from table 32763 go beyond"),
    ({"unit": 0}, "monitor 1.unit: 0 out of range 1..247"),
    ({"colour": 1}, "monitor 1.colour: unknown key"),
])
def test_a_bad_map_is_refused_naming_its_key(change: dict, problem: str) -> None:
    _, problems = parse_monitors([{**GOOD, **change}])
    assert problems and problems[0].startswith(problem)


def test_a_map_needs_a_line_in_monitor_mode() -> None:
    maps, _ = parse_monitors([GOOD, {**GOOD, "line": "meters", "table": 100},
                              {**GOOD, "line": "gone", "table": 200}])
    assert monitor_problems(maps, {"tap": "monitor", "meters": "slave"}) == [
        "monitor 2.line 'meters': the line is in slave mode; a map reads a line in monitor mode",
        "monitor 3.line 'gone': no such line"]


def test_overlapping_table_ranges_are_refused() -> None:
    maps, _ = parse_monitors([GOOD, {**GOOD, "unit": 2, "table": 9}])
    assert monitor_problems(maps, {"tap": "monitor"}) == [
        "monitor 2.table: registers 9..9 are monitor 1's already"]


# --- through check-config ---------------------------------------------------------------------

TAP = '[[line]]\nname = "tap"\nmode = "monitor"\ndevice = "/dev/ttyUSB1"\n'


def monitor(**keys) -> str:
    fields = {**GOOD, **keys}
    return "[[monitor]]\n" + "".join(f"{k} = {v!r}\n".replace("'", '"')
                                     for k, v in fields.items())


def test_the_readme_example_passes_check_config(tmp_path) -> None:
    from tests.harness import CHECKOUT
    readme = (CHECKOUT / "README.md").read_text()
    start = readme.index('[[line]]\nname = "plc-bus"')
    _, result = check_config(tmp_path, SERIAL + readme[start:readme.index("```", start)])
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("text, problem", [
    (TAP + monitor(line="serial"), "monitor 1.line 'serial': the line is in slave mode"),
    (TAP + monitor(line="nowhere"), "monitor 1.line 'nowhere': no such line"),
    (TAP + monitor(function=6), "monitor 1.function: 6 out of range 1..4"),
    (TAP + monitor() + monitor(unit=2, table=5), "monitor 2.table: registers 5..9"),
    (TAP + monitor(table=32767), "monitor 1.quantity: 10 registers from table 32767"),
    (TAP + '[[route]]\nunits = "5"\nline = "tap"\n',
     "route 1.line 'tap': the line is in monitor mode"),
    (TAP.replace('"/dev/ttyUSB1"\n', '"/dev/ttyUSB1"\nstout = 100\n'),
     "line tap.stout: applies to slave-mode lines only"),
])
def test_check_config_refuses(tmp_path, text: str, problem: str) -> None:
    assert problem in refusal(tmp_path, SERIAL + text)


def test_config_show_monitor_prints_the_maps_as_the_file_reads_them(tmp_path) -> None:
    import tomllib

    from click.testing import CliRunner

    from mbgw.cli import main
    path, result = check_config(tmp_path, SERIAL + TAP + monitor() + monitor(unit=2, table=10))
    assert result.exit_code == 0, result.output
    shown = CliRunner().invoke(main, ["config", "show", "monitor", "--config", str(path)],
                               prog_name="mbgw")
    assert shown.exit_code == 0, shown.output
    assert parse_monitors(tomllib.loads(shown.output)["monitor"]) == parse_monitors(
        [GOOD, {**GOOD, "unit": 2, "table": 10}])
