"""A target line (mbgw.slave.targets) whose device is not there: every exchange handed to it
is refused at once on its own thread (0x0A, or nothing without `exception`), and the face is
told through Exchange.done; stopping it refuses what is left."""
import dataclasses
import queue

import pytest

from mbgw.config.lines import LineConfig
from mbgw.config.model import SerialConfig, SlaveConfig
from mbgw.ops.reload import ReloadReport
from mbgw.routing.queue import Exchange
from mbgw.slave.targets import TargetLine, TargetLines

DEADLINE_S = 5.0


@pytest.fixture
def absent(tmp_path):
    return LineConfig("meters", SerialConfig(str(tmp_path / "ttyUSB-not-there")))


def ask(target: TargetLine, address: int, request: bytes):
    told: queue.Queue = queue.Queue()
    target.inbox.submit(Exchange("panel", address, request, 0,
                                 lambda ex, reply, outcome: told.put((ex, reply, outcome)),
                                 context="mine"))
    return told.get(timeout=DEADLINE_S)


@pytest.mark.parametrize("exception, reply", [(True, b"\x83\x0a"), (False, None)])
def test_a_line_not_there_refuses_at_once(absent, exception, reply):
    cfg = SlaveConfig(SerialConfig("/dev/null"), exception=exception, lines=(absent,))
    target = TargetLine(cfg, absent)
    target.start()
    try:
        exchange, got, outcome = ask(target, 1, bytes.fromhex("03 0000 0001"))
        assert (got, outcome, exchange.context) == (reply, "line down", "mine")
        assert target.status() == {"name": "meters", "device": absent.serial.device,
                                   "mode": "slave", "state": "waiting", "requests": 1,
                                   "replies": 1 if exception else 0, "timeouts": 0}
    finally:
        target.stop()
        target.join()


def test_lines_added_and_removed_by_name(absent):
    cfg = SlaveConfig(SerialConfig("/dev/null"), lines=(absent,))
    inboxes: dict = {}
    lines = TargetLines(cfg, inboxes)
    assert list(inboxes) == ["meters"]
    lines.start()
    try:
        removed = lines.reconfigure(dataclasses.replace(cfg, lines=()))
        assert [t.config.name for t in removed] == ["meters"] and inboxes == {}
        for target in removed:
            target.stop()
            target.join()
    finally:
        lines.stop()
        lines.join()


def test_a_line_added_whose_device_does_not_open_is_told(tmp_path, absent):
    not_a_tty = tmp_path / "plain-file"
    not_a_tty.write_text("")
    cfg = SlaveConfig(SerialConfig("/dev/null"))
    inboxes: dict = {}
    lines = TargetLines(cfg, inboxes)
    report = ReloadReport()
    bad = LineConfig("bad", SerialConfig(str(not_a_tty)))
    try:
        assert lines.reconfigure(dataclasses.replace(cfg, lines=(bad, absent)), report) == []
        assert list(report.not_applied) == ["lines"]
        assert "line bad:" in report.not_applied["lines"]
        assert list(inboxes) == ["meters"] and list(lines.lines) == ["meters"]
    finally:
        lines.stop()
        lines.join()
