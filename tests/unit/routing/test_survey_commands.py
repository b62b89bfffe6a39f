"""The control commands of `mbgw scan/probe --line` (mbgw.routing.survey): which lines they
ask, what a request must say, and one read handed to the line's inbox and answered from the
line's thread (here a thread of the test's)."""
import asyncio
import select
import threading

import pytest

from mbgw.config.model import LineFormat, SerialConfig
from mbgw.ops.trace import Outcome
from mbgw.routing.queue import Inbox, SurveyRead
from mbgw.routing.survey import SurveyLine, survey_commands


@pytest.fixture
def inbox():
    box = Inbox()
    yield box
    box.close()


def commands(inbox: Inbox, protocol: str = "rtu") -> dict:
    serial = SerialConfig("/dev/ttyUSB0", 19200, LineFormat.parse("8e1"), protocol=protocol)
    return survey_commands(lambda: {"serial": SurveyLine(inbox, serial), "panel": "master"})


def test_the_line_settings_of_a_line_in_slave_mode(inbox):
    reply = commands(inbox)["survey-line"]({"line": "serial", "uid": 0})
    assert reply == {"line": "serial", "device": "/dev/ttyUSB0", "baudrate": 19200,
                     "format": "8e1"}


@pytest.mark.parametrize("request_, error", [
    ({"line": "nope"}, "no line 'nope' (lines: panel, serial)"),
    ({"line": "panel"}, "line panel is in master mode"),
    ({}, 'expected {"line": NAME}'),
])
def test_a_line_that_cannot_be_surveyed_is_named(inbox, request_, error):
    assert commands(inbox)["survey-line"](request_)["error"].startswith(error)


def test_an_ascii_line_is_refused(inbox):
    error = commands(inbox, "ascii")["survey-line"]({"line": "serial"})["error"]
    assert error == "line serial is an ASCII line: scan and probe ask RTU lines only"


@pytest.mark.parametrize("fields, error", [
    ({"unit": 0, "pdu": "03", "timeout_ms": 100}, '"unit"'),
    ({"unit": 248, "pdu": "03", "timeout_ms": 100}, '"unit"'),
    ({"unit": 1, "pdu": "0x", "timeout_ms": 100}, '"pdu"'),
    ({"unit": 1, "pdu": "", "timeout_ms": 100}, '"pdu"'),
    ({"unit": 1, "pdu": "03", "timeout_ms": 0}, '"timeout_ms"'),
    ({"unit": "1", "pdu": "03", "timeout_ms": 100}, '"unit"'),
])
def test_a_bad_read_request_is_refused_before_the_line(inbox, fields, error):
    reply = asyncio.run(commands(inbox)["survey-read"]({"line": "serial", **fields}))
    assert reply["error"].startswith(error)
    assert inbox.drain() == []


@pytest.mark.parametrize("reply, outcome, expected", [
    (b"\x03\x02\x00\x2a", Outcome.REPLY, {"pdu": "0302002a", "response_ns": 1234}),
    (b"\x83\x02", Outcome.DEVICE_EXCEPTION, {"pdu": "8302", "response_ns": 1234}),
    (None, Outcome.TIMEOUT, {"pdu": None, "response_ns": 0}),
    (b"\x83\x0a", Outcome.LINE_DOWN, {"error": "line serial: line down"}),
])
def test_a_read_goes_through_the_inbox_and_its_outcome_comes_back(inbox, reply, outcome,
                                                                   expected):
    def line_thread() -> None:
        [survey] = _wait_for(inbox)
        assert isinstance(survey, SurveyRead)
        assert (survey.address, survey.pdu, survey.timeout_ms) == (5, b"\x03\x00\x00\x00\x01",
                                                                   250)
        survey.response_ns = 1234
        survey.done(survey, reply, outcome)

    thread = threading.Thread(target=line_thread)
    thread.start()
    got = asyncio.run(commands(inbox)["survey-read"](
        {"line": "serial", "unit": 5, "pdu": "0300000001", "timeout_ms": 250}))
    thread.join()
    assert got == expected


def _wait_for(inbox: Inbox) -> list:
    select.select([inbox.wake_fd], [], [], 5)
    return inbox.drain()
