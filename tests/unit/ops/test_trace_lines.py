"""One trace hub for every line: the line filter takes the daemon's line names, each line's
view names its events, every line's raw watcher is told, and the outcomes are one
vocabulary that reads as plain strings in JSON."""
import asyncio
import json

import pytest

from mbgw.cli.render_lines import line_status
from mbgw.ops.trace import Outcome, TraceHub, filters

LINES = ("serial", "meters", "panel")


def test_the_line_filter_takes_any_line_of_the_daemon_and_names_them_for_another():
    assert filters({"line": "panel"}, LINES) == {"line": "panel"}
    with pytest.raises(ValueError) as refused:
        filters({"line": "tanks"}, LINES)
    assert str(refused.value) == \
        "trace: line 'tanks': this daemon's lines are serial, meters, panel"


def test_each_line_names_its_events_and_the_filter_keeps_one_line():
    async def run() -> list[dict]:
        hub = TraceHub()
        queue = hub.subscribe(wanted={"line": "meters"})
        hub.for_line("serial").emit_threadsafe({"direction": "request", "unit": 1})
        hub.for_line("meters").emit_threadsafe({"direction": "request", "unit": 32})
        hub.emit({"direction": "request", "unit": 250, "line": None})     # the table's
        got = [await asyncio.wait_for(queue.get(), 5)]
        assert queue.empty()
        return got
    assert asyncio.run(run()) == [{"direction": "request", "unit": 32, "line": "meters"}]


def test_every_lines_raw_watcher_is_told_and_a_gone_one_no_more():
    async def run() -> list[tuple[str, bool]]:
        hub = TraceHub()
        told: list[tuple[str, bool]] = []
        serial = lambda on: told.append(("serial", on))    # noqa: E731
        meters = lambda on: told.append(("meters", on))    # noqa: E731
        hub.add_raw_watcher(serial)
        hub.for_line("meters").add_raw_watcher(meters)
        assert hub.raw_view
        queue = hub.subscribe(raw=True)
        hub.for_line("meters").remove_raw_watcher(meters)
        hub.unsubscribe(queue)
        return told
    assert asyncio.run(run()) == [("serial", True), ("meters", True), ("serial", False)]
    assert not TraceHub().raw_view           # transparent mode's: no line to watch


def test_outcomes_are_their_strings():
    assert json.dumps({"outcome": Outcome.DEVICE_DOWN}) == '{"outcome": "device down"}'
    assert Outcome.LATE == "late reply, dropped" and f"{Outcome.BAD_REPLY}: x" == \
        "not the answer: x"


def test_status_line_narrows_to_one_line_or_names_the_known_ones():
    s = {"mode": "slave", "version": "0", "pid": 1,
         "lines": [{"name": "serial"}, {"name": "meters"}],
         "routes": [{"face": "tcp", "target": "line serial", "units": "1-31"},
                    {"face": "tcp", "target": "line meters", "units": "32-63"},
                    {"face": "tcp", "target": "table", "units": "247-254"}]}
    one = line_status(s, "meters")
    assert one["line"] == {"name": "meters"} and [r["units"] for r in one["routes"]] == \
        ["32-63"]
    with pytest.raises(LookupError) as unknown:
        line_status(s, "tanks")
    assert str(unknown.value) == \
        "status --line tanks: no such line (this daemon's lines: serial, meters)"
