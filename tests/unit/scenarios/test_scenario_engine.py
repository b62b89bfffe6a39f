"""One runner's scenarios (mbgw.scenarios.engine) with a real exchange table and a virtual
clock: runs, results stored, states and counters, the change trigger through the table's
watch and eventfd, FC 7's flag, stale data answered 0x0B, enable/disable and reload."""
import logging
import select
import time

import pytest

from mbgw.config.scenario import parse_scenario
from mbgw.scenarios.engine import Scenarios

H = bytes.fromhex


def sc(name, **keys):
    base = {"name": name, "slave": 1, "function": 3, "address": 0, "quantity": 2,
            "table": 0, "cycle": 1000}
    base.update(keys)
    return parse_scenario({k: v for k, v in base.items() if v is not None}, "s")


def engine(table, clock, *configs):
    return Scenarios(configs, table, "serial", clock=clock)


def status(e, name):
    return next(s for s in e.status() if s["name"] == name)


def test_a_read_runs_and_stores(table, clock):
    e = engine(table, clock, sc("r"), sc("t", slave=None, server="h"))
    assert [s["name"] for s in e.status()] == ["r"]          # the TCP one is not this runner's
    assert status(e, "r")["state"] == "starting"
    run = e.next(clock.now)
    assert run.pdu == H("03 00 00 00 02")
    clock.now += 0.05
    assert e.done(run, H("03 04 00 07 00 08"), None, retries=1).ok
    assert table.read(0, 2) == [7, 8]
    s = status(e, "r")
    assert (s["state"], s["runs"], s["successes"], s["retries"], s["last_latency_ms"]) == \
        ("running", 1, 1, 1, 50.0)
    assert e.due_in(clock.now) == pytest.approx(0.95)


def test_errors_logged_once_and_fc7_flag(table, clock, caplog):
    caplog.set_level(logging.INFO, "mbgw.scenarios")
    e = engine(table, clock, sc("r"))
    for _ in range(3):
        run = e.next(clock.now)
        e.done(run, None, "timeout", retries=2)
        clock.now += 1
    s = status(e, "r")
    assert (s["state"], s["message"], s["errors"], s["retries"]) == \
        ("error", "timeout, no answer from slave after retrying", {"timeout": 3}, 6)
    assert table.answer(H("07")) == H("07 02")
    assert [r.getMessage() for r in caplog.records] == \
        ["scenario r (slave 1): timeout, no answer from slave after retrying"]
    e.done(e.next(clock.now), H("03 04 00 01 00 02"), None)
    assert status(e, "r")["state"] == "running" and table.answer(H("07")) == H("07 00")
    assert caplog.records[-1].getMessage() == "scenario r (slave 1): running again"


def test_change_trigger_through_the_table(table, clock):
    e = engine(table, clock, sc("w", function=16, table=10, cycle=None, trigger="change"))
    assert e.due_in(clock.now) is None
    table.write(10, [0, 0])              # the table's values, but written for the first time
    assert select.select([e.wake_fd], [], [], 0)[0]
    run = e.next(clock.now)
    assert run.pdu == H("10 00 00 00 02 04 00 00 00 00")
    e.done(run, H("10 00 00 00 02"), None)
    table.write(10, [0, 0])                                    # the same values: no change
    assert e.due_in(clock.now) is None
    assert not select.select([e.wake_fd], [], [], 0)[0]
    table.write(11, [5])
    assert select.select([e.wake_fd], [], [], 0)[0]
    assert e.due_in(clock.now) == 0.0
    run = e.next(clock.now)
    assert run.pdu == H("10 00 00 00 02 04 00 00 00 05")
    assert e.next(clock.now) is None
    e.done(run, H("10 00 00 00 02"), None)
    assert e.due_in(clock.now) is None and status(e, "w")["state"] == "running"


def test_stale_after_answers_0x0b_until_fresh_data(table, clock):
    e = engine(table, clock, sc("r", table=40, **{"stale-after": 2000}))
    e.done(e.next(clock.now), H("03 04 00 01 00 02"), None)
    assert table.answer(H("03 00 28 00 02")) == H("03 04 00 01 00 02")
    clock.now += 1.5
    assert e.due_in(clock.now) == pytest.approx(0.0)            # the cycle is due
    e.done(e.next(clock.now), None, "timeout")
    assert e.due_in(clock.now) == pytest.approx(0.5)            # the stale check
    clock.now += 0.5
    e.tick(clock.now)
    assert table.answer(H("03 00 28 00 02")) == H("83 0b")
    assert table.answer(H("03 00 29 00 01")) == H("83 0b")      # touching the range
    assert table.answer(H("03 00 2a 00 01")) == H("03 02 00 00")  # beside it
    assert table.answer(H("17 00 27 00 02 00 00 00 01 02 00 00")) == H("97 0b")
    e.done(e.next(clock.now), H("03 04 00 03 00 04"), None)
    assert table.answer(H("03 00 28 00 02")) == H("03 04 00 03 00 04")


def test_stale_bits(table):
    table.set_stale(2, 1, True)                # bits 32..47
    assert table.answer(H("01 00 1f 00 01")) == H("01 01 00")     # bit 31
    assert table.answer(H("01 00 1f 00 02")) == H("81 0b")
    assert table.answer(H("02 00 30 00 08")) == H("02 01 00")     # bit 48..
    table.set_stale(2, 1, False)
    assert table.answer(H("01 00 1f 00 02")) == H("01 01 00")


def test_in_error_since_the_first_failure_until_it_runs_again(table, clock):
    e = engine(table, clock, sc("r"))
    assert status(e, "r")["error_since"] is None
    before = time.time()
    e.done(e.next(clock.now), None, "timeout", retries=0)
    since = status(e, "r")["error_since"]
    assert before <= since <= time.time()
    clock.now += 1
    e.done(e.next(clock.now), None, "crc", retries=0)          # still in error: same since
    assert status(e, "r")["error_since"] == since
    clock.now += 1
    e.done(e.next(clock.now), H("03 04 00 01 00 02"), None)
    assert status(e, "r")["error_since"] is None


def test_enable_disable(table, clock):
    e = engine(table, clock, sc("r"), sc("q", enabled=False))
    assert status(e, "q")["state"] == "disabled"
    assert e.enable("r", False) and e.enable("q", True)
    assert not e.enable("nope", True)
    run = e.next(clock.now)
    assert run.scenario.name == "q" and e.next(clock.now) is None
    assert status(e, "r")["state"] == "disabled"


def test_disabling_a_scenario_in_error_does_not_log_it_running_again(table, clock, caplog):
    caplog.set_level(logging.INFO, "mbgw.scenarios")
    e = engine(table, clock, sc("r"))
    e.done(e.next(clock.now), None, "timeout", retries=0)
    assert status(e, "r")["state"] == "error" and table.answer(H("07")) == H("07 02")
    assert e.enable("r", False)
    assert status(e, "r")["state"] == "disabled" and table.answer(H("07")) == H("07 00")
    messages = [r.getMessage() for r in caplog.records]
    assert messages[-1] == "scenario r disabled"
    assert not any("running again" in m for m in messages), messages


def test_reload_keeps_unchanged_and_restarts_changed(table, clock):
    e = engine(table, clock, sc("a"), sc("b"), sc("c"))
    for _ in range(3):
        e.done(e.next(clock.now), H("03 04 00 01 00 02"), None)
    clock.now += 0.3
    e.reconfigure([sc("a"), sc("b", quantity=3), sc("d")])
    assert [s["name"] for s in e.status()] == ["a", "b", "d"]
    assert (status(e, "a")["runs"], status(e, "a")["state"]) == (1, "running")
    assert (status(e, "b")["runs"], status(e, "b")["state"]) == (0, "starting")
    assert e.due_in(clock.now) == 0.0
    assert [e.next(clock.now).scenario.name for _ in range(2)] == ["b", "d"]
    assert e.next(clock.now) is None and e.due_in(clock.now) == pytest.approx(0.7)


def test_test_returns_data_without_storing(table, clock):
    e = engine(table, clock)
    result = e.test(sc("x", table=5), lambda pdu: (H("03 04 00 09 00 0a"), None, 0))
    assert (result["ok"], result["data"], result["request"]) == (True, [9, 10],
                                                                  "03 00 00 00 02")
    assert table.read(5, 2) == [0, 0]
    result = e.test(sc("x"), lambda pdu: (None, "timeout", 2))
    assert result["message"] == "timeout, no answer from slave after retrying"


def test_a_retrying_run_says_so_until_it_ends(table, clock):
    """VPGate 8.2/8.3: "Slave not responding, retrying..." ("Server ..." for a TCP one)."""
    e = engine(table, clock, sc("r"))
    run = e.next(clock.now)
    e.retrying(run.scenario)
    assert status(e, "r")["message"] == "slave not responding, retrying..."
    e.done(run, None, "timeout", retries=1)
    assert (status(e, "r")["state"], status(e, "r")["message"]) == \
        ("error", "timeout, no answer from slave after retrying")
    clock.now += 1.0
    run = e.next(clock.now)
    e.retrying(run.scenario)
    assert status(e, "r")["message"] == "slave not responding, retrying..."
    e.done(run, H("03 04 00 07 00 08"), None, retries=1)
    assert (status(e, "r")["state"], status(e, "r")["message"]) == ("running", "")
    tcp = Scenarios([sc("t", slave=None, server="h")], table, "tcp", clock=clock)
    run = tcp.next(clock.now)
    tcp.retrying(run.scenario)
    assert status(tcp, "t")["message"] == "server not responding, retrying..."


def test_a_retry_of_a_scenario_replaced_meanwhile_leaves_the_new_one_alone(table, clock):
    e = engine(table, clock, sc("r"))
    run = e.next(clock.now)
    e.reconfigure([sc("r", quantity=3)])
    e.retrying(run.scenario)
    assert status(e, "r")["message"] == ""
