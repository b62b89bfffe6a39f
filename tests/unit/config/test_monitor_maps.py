"""[[monitor]] maps: each table's keys, and what check-config refuses across them."""
import pytest

from mbgw.config.monitor import MonitorMap, monitor_problems, parse_monitors

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
