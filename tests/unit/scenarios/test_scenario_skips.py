"""The runs a scenario engine (mbgw.scenarios.engine) does not hand to its runner: a write
whose table registers nobody has written since start ("waiting for data", unless
send-unwritten), and a run for a device that is down but for its probe (the demotion rule of
mbgw.ops.device_stats, through mbgw.scenarios.health).  A real exchange table, the real
DeviceHealth, a virtual clock for the schedule."""
import logging
import re

import pytest

from mbgw.cli.render_scenarios import format_scenarios
from mbgw.config.model import Demotion
from mbgw.ops.device_stats import DOWN, DeviceHealth, HealthRule
from mbgw.scenarios.engine import Scenarios
from mbgw.scenarios.health import SerialHealth, ServerHealth
from tests.unit.scenarios.test_scenario_engine import sc as scenario

H = bytes.fromhex


def sc(name, **keys):
    """A write of holding registers 20-21 from the table's 20-21 (keys: others)."""
    return scenario(name, **{"function": 16, "address": 20, "table": 20, **keys})


def status(e, name):
    return next(s for s in e.status() if s["name"] == name)


# --- waiting for data ---

def test_a_cyclic_write_waits_until_every_register_it_sends_was_written(table, clock, caplog):
    caplog.set_level(logging.INFO, "mbgw.scenarios")
    e = Scenarios([sc("setpoint")], table, "serial", clock=clock)
    assert e.due_in(clock.now) == 0.0
    assert e.next(clock.now) is None                          # nothing sent: zeros nobody gave
    s = status(e, "setpoint")
    assert (s["state"], s["runs"], s["message"]) == \
        ("starting", 0, "waiting for data: table register 20 not written since start")
    table.write(20, [42])
    clock.now += 1
    assert e.next(clock.now) is None
    assert status(e, "setpoint")["message"] == \
        "waiting for data: table register 21 not written since start"
    table.answer(H("06 0015 002b"))                           # a client writes the other
    clock.now += 1
    run = e.next(clock.now)
    assert run.pdu == H("10 0014 0002 04 002a 002b")
    e.done(run, H("10 0014 0002"), None)
    assert (status(e, "setpoint")["state"], status(e, "setpoint")["message"]) == ("running", "")
    waiting = [r.getMessage() for r in caplog.records if "waiting" in r.getMessage()]
    assert len(waiting) == 1, waiting                        # logged once, when it began


def test_send_unwritten_sends_the_tables_zeros_at_once(table, clock):
    e = Scenarios([sc("raw", **{"send-unwritten": True})], table, "serial", clock=clock)
    assert e.next(clock.now).pdu == H("10 0014 0002 04 0000 0000")


@pytest.mark.parametrize("keys, first_write", [
    ({"function": 5, "quantity": None, "table": "30.4"}, (30, [1])),        # the bit's register
    ({"function": 15, "quantity": 20, "table": "30.10"}, (30, [0, 0])),     # bits in 30 and 31
    ({"function": 6, "quantity": None}, (20, [0])),
    ({"function": 23, "address": None, "quantity": None, "table": None, "read-address": 0,
      "read-quantity": 1, "read-table": 50, "write-address": 5, "write-quantity": 2,
      "write-table": 60}, (60, [0, 0])),                                     # its write part
])
def test_the_registers_a_write_waits_for(table, clock, keys, first_write):
    e = Scenarios([sc("w", **keys)], table, "serial", clock=clock)
    assert e.next(clock.now) is None
    table.write(first_write[0], first_write[1])
    clock.now += 1
    assert e.next(clock.now) is not None


def test_reads_never_wait(table, clock):
    e = Scenarios([sc("r", function=3)], table, "serial", clock=clock)
    assert e.next(clock.now).pdu == H("03 0014 0002")


def test_a_change_write_goes_on_the_first_write_even_of_the_tables_value(table, clock):
    e = Scenarios([sc("copy", cycle=None, trigger="change")], table, "serial", clock=clock)
    table.write(20, [0])                      # 21 not written yet: taken, but waiting
    assert e.due_in(clock.now) == 0.0 and e.next(clock.now) is None
    assert status(e, "copy")["message"].startswith("waiting for data")
    table.write(21, [0])                      # the same value, but its first write
    assert e.due_in(clock.now) == 0.0
    assert e.next(clock.now).pdu == H("10 0014 0002 04 0000 0000")


def test_scenario_test_of_an_unwritten_write_is_refused_before_the_line(table, clock):
    e = Scenarios([], table, "serial", clock=clock)
    result = e.request_test(sc("t"), wait_s=0.01)
    assert result == {"error": "waiting for data: table register 20 not written since start: "
                               "nothing sent (send-unwritten=true sends it all the same)"}


# --- demotion ---

def devices(down_after=2, interval_ms=1000) -> DeviceHealth:
    return DeviceHealth(rule=HealthRule(Demotion(down_after, interval_ms)))


def fail(table_, address, times):
    for _ in range(times):
        table_.get(address).failed()


def test_a_down_device_gets_no_run_but_the_probe(table, clock):
    """The probe times are DeviceStats's (time.monotonic()): the virtual clock starts there,
    and each step lands a whole period after the last one planned."""
    line = devices()
    fail(line, 5, 2)
    assert line.get(5).health == DOWN
    clock.now = line.get(5).probe_at - 0.5          # down, its probe not due yet
    e = Scenarios([sc("poll", slave=5, function=3), sc("other", slave=6, function=3)], table,
                  "serial", clock=clock)
    e.health = SerialHealth(line)
    # both due: "poll" skipped, "other" handed over in the same call
    run = e.next(clock.now)
    assert run.scenario.name == "other" and not run.probe
    e.done(run, H("03 04 0000 0000"), None)
    s = status(e, "poll")
    assert (s["state"], s["message"], s["errors"], s["runs"]) == \
        ("error", "device down", {"device-down": 1}, 1)
    assert 0 < s["next_probe_in_s"] <= 1.0 and status(e, "other")["next_probe_in_s"] is None
    assert line.get(5).demoted_rejects == 1
    shown = format_scenarios(e.status(), 0)
    assert re.fullmatch(r"    error: device down, next probe in [01]\.\d s", shown[3]), shown
    clock.now += 1                                   # past the probe's time
    run = e.next(clock.now)
    assert run.scenario.name == "poll" and run.probe              # the probe goes
    line.get(5).failed()                                          # ... and fails
    e.done(run, None, "timeout", retries=2)
    s = status(e, "poll")
    assert (s["message"], s["errors"]) == ("device down", {"device-down": 1, "timeout": 1})
    run = e.next(clock.now)
    assert run.scenario.name == "other"
    e.done(run, H("03 04 0000 0000"), None)
    clock.now += 2                                   # the next probe, twice the interval on
    assert clock.now > line.get(5).probe_at
    runs = {r.scenario.name: r for r in iter(lambda: e.next(clock.now), None)}
    assert runs["poll"].probe
    line.get(5).answered(5.0, None)
    e.done(runs["poll"], H("03 04 0001 0002"), None)
    e.done(runs["other"], H("03 04 0001 0002"), None)
    assert (status(e, "poll")["state"], status(e, "poll")["message"]) == ("running", "")
    assert status(e, "poll")["next_probe_in_s"] is None
    clock.now += 1
    assert {r.scenario.name: r.probe for r in iter(lambda: e.next(clock.now), None)} == \
        {"poll": False, "other": False}


def test_a_change_write_skipped_while_down_is_sent_once_the_device_is_back(table, clock):
    line = devices(down_after=1, interval_ms=60000)
    e = Scenarios([sc("copy", slave=5, function=6, quantity=None, cycle=None,
                      trigger="change")], table, "serial", clock=clock)
    e.health = SerialHealth(line)
    fail(line, 5, 1)
    table.write(20, [7])
    assert e.due_in(clock.now) == 0.0 and e.next(clock.now) is None      # skipped
    assert status(e, "copy")["message"] == "device down"
    assert e.due_in(clock.now) is None                                  # nothing due meanwhile
    line.get(5).answered(3.0, None)                 # a client's probe: the device is back
    assert e.due_in(clock.now) == 0.0
    table.write(20, [8])
    assert e.next(clock.now).pdu == H("06 0014 0008")                   # the data as it is now


def test_a_tcp_server_is_judged_by_the_same_rule(table, clock):
    health = ServerHealth(HealthRule(Demotion(3, 500)))
    e = Scenarios([sc("remote", slave=None, server="127.0.0.1:1502", function=3)], table,
                  "tcp", clock=clock)
    e.health = health
    server = health.of("127.0.0.1", 1502)
    for _ in range(3):
        server.failed()
    assert server.health == DOWN and server.name == "scenario server 127.0.0.1:1502"
    e.next(server.probe_at - 0.1)
    assert status(e, "remote")["message"] == "server down"
    assert 0 < status(e, "remote")["next_probe_in_s"] <= 0.5
    assert health.of("::1", 502).name == "scenario server [::1]:502"


def test_a_change_write_not_answered_is_sent_again_until_its_device_is_down(table, clock):
    """A timeout leaves the write owed: sent again at once (the table's data then) while the
    device is up, not while it is down (its probe is a client's), again once it is back."""
    line = devices(down_after=2, interval_ms=60000)
    e = Scenarios([sc("copy", slave=5, function=6, quantity=None, cycle=None,
                      trigger="change")], table, "serial", clock=clock)
    e.health = SerialHealth(line)
    table.write(20, [7])
    run = e.next(clock.now)
    assert run.pdu == H("06 0014 0007")
    line.get(5).failed()
    e.done(run, None, None)                         # no reply: a timeout
    assert e.due_in(clock.now) == 0.0
    table.write(20, [8])
    run = e.next(clock.now)
    assert run.pdu == H("06 0014 0008")             # the data as it is now
    line.get(5).failed()                            # the device is down now
    e.done(run, None, None)
    assert e.due_in(clock.now) is None and e.next(clock.now) is None
    line.get(5).answered(3.0, None)
    assert e.next(clock.now).pdu == H("06 0014 0008")


def test_a_change_write_answered_with_an_exception_is_not_sent_again(table, clock):
    e = Scenarios([sc("copy", slave=5, function=6, quantity=None, cycle=None,
                      trigger="change")], table, "serial", clock=clock)
    e.health = SerialHealth(devices())
    table.write(20, [7])
    run = e.next(clock.now)
    e.done(run, H("86 02"), None)
    assert e.due_in(clock.now) is None and e.next(clock.now) is None
