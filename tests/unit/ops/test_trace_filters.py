"""The trace's filters (mbgw.ops.trace): what a bad one is told, and which events pass."""
import pytest

from mbgw.ops.trace import filters, matches

REQUEST = {"direction": "request", "client": 3, "unit": 11, "function": 3}
EXCEPTION = {"direction": "reply", "client": 3, "unit": 11, "function": 0x83,
             "outcome": "device exception"}
RUN = {"direction": "reply", "scenario": "meter", "client": None, "unit": 1, "function": 3,
       "outcome": "ok"}
RUN_FAILED = {"direction": "no reply", "scenario": "meter", "client": None, "unit": 1,
              "function": 3, "outcome": "timeout"}
LATE = {"direction": "late", "client": 3, "unit": 11, "function": 3,
        "outcome": "late reply, dropped"}
NOISE = {"raw": True, "kind": "noise", "line": "serial"}
REPLY_BURST = {"raw": True, "kind": "reply", "line": "serial"}


@pytest.mark.parametrize("given, message", [
    ({"unit": "x"}, "trace: unit 'x': expected a number"),
    ({"unit": 256}, "trace: unit 256: expected 0..255"),
    ({"function": 0}, "trace: function 0: expected 1..127"),
    ({"line": "rs485"}, "trace: line 'rs485': this daemon has one line, serial"),
    ({"colour": "red"}, "trace: unknown filter 'colour' (known: unit, client, function, "
                        "scenario, line, errors)"),
])
def test_a_bad_filter_is_named(given, message):
    with pytest.raises(ValueError) as err:
        filters(given)
    assert str(err.value) == message


def test_filters_keep_what_is_set():
    assert filters({"unit": "0x0b", "client": None, "errors": False, "scenario": "meter"}) == \
        {"unit": 11, "scenario": "meter"}


@pytest.mark.parametrize("wanted, passing", [
    ({}, [REQUEST, EXCEPTION, RUN, RUN_FAILED, NOISE, REPLY_BURST]),
    ({"unit": 11}, [REQUEST, EXCEPTION, NOISE, REPLY_BURST]),
    ({"function": 3}, [REQUEST, EXCEPTION, RUN, RUN_FAILED, NOISE, REPLY_BURST]),
    ({"client": 3}, [REQUEST, EXCEPTION, NOISE, REPLY_BURST]),
    ({"scenario": "meter"}, [RUN, RUN_FAILED, NOISE, REPLY_BURST]),
    ({"errors": True}, [EXCEPTION, RUN_FAILED, NOISE, LATE]),
    ({"line": "serial"}, [REQUEST, EXCEPTION, RUN, RUN_FAILED, NOISE, REPLY_BURST]),
])
def test_which_events_pass(wanted, passing):
    events = [REQUEST, EXCEPTION, RUN, RUN_FAILED, NOISE, REPLY_BURST]
    if wanted.get("errors"):
        events.append(LATE)
    assert [e for e in events if matches(e, wanted)] == passing


def test_a_line_passes_a_serial_faces_requests_to_it():
    # a serial master on line panel reads address 1 of line meters: panel's events
    to_meters = {"direction": "request", "line": "panel", "address": 7, "unit": 1,
                 "function": 3, "server": "line meters"}
    to_a_server = {**to_meters, "server": "127.0.0.1:502"}
    on_meters = {"direction": "request", "line": "meters", "client": 1, "unit": 32,
                 "function": 3}
    events = [to_meters, to_a_server, on_meters, NOISE]
    assert [e for e in events if matches(e, {"line": "meters"})] == [to_meters, on_meters]
    assert [e for e in events if matches(e, {"line": "panel"})] == [to_meters, to_a_server]
