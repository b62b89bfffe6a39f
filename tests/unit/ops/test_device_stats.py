"""Per-device statistics and health (mbgw.ops.device_stats): the state machine up / degraded /
down, logged once per change; exception replies by code; the latency buckets; reset."""
import logging
from types import SimpleNamespace

import pytest

from mbgw.config.model import (
    DEFAULT_DOWN_AFTER,
    DEFAULT_PROBE_INTERVAL_MS,
    PROBE_BACKOFF_MAX_MS,
    Demotion,
)
from mbgw.ops import device_stats
from mbgw.ops.device_stats import (
    COUNTS,
    LATENCY_BUCKETS_MS,
    RECENT_WINDOW,
    DeviceHealth,
    DeviceStats,
    HealthRule,
)


class Clock:
    """Both clocks of the module: time.time() and time.monotonic(), moved together."""
    def __init__(self) -> None:
        self.now = 1_000_000.0

    def time(self) -> float:
        return self.now

    def monotonic(self) -> float:
        return self.now - 999_000.0


@pytest.fixture
def clock(monkeypatch):
    """The module's time.time() and time.monotonic(), under the test's control."""
    c = Clock()
    monkeypatch.setattr(device_stats, "time", SimpleNamespace(time=c.time,
                                                              monotonic=c.monotonic))
    return c


@pytest.fixture
def health_log(caplog):
    """The health messages logged so far, as (level, message)."""
    caplog.set_level(logging.DEBUG, logger="mbgw.devices")

    def records():
        return [(r.levelname, r.getMessage()) for r in caplog.records
                if r.name == "mbgw.devices"]
    return records


def test_the_spec_constants_are_what_the_tests_assume():
    assert DEFAULT_DOWN_AFTER == 3
    assert (DEFAULT_PROBE_INTERVAL_MS, PROBE_BACKOFF_MAX_MS) == (5000, 60000)
    assert RECENT_WINDOW == 20
    assert LATENCY_BUCKETS_MS == (2, 5, 10, 25, 50, 100, 250, 500, 1000, 2500, 5000)


def test_a_new_device_is_up_with_nothing_counted(clock):
    d = DeviceStats(9)
    snap = d.snapshot()
    assert snap["health"] == "up" and snap["health_since"] == clock.now
    assert snap["last_success"] is None and snap["consecutive_failures"] == 0
    assert {name: snap[name] for name in COUNTS} == dict.fromkeys(COUNTS, 0)
    assert snap["exceptions"] == {} and snap["gateway_exceptions"] == {}
    assert sum(snap["latency_buckets_ms"].values()) == 0 and snap["latency_sum_ms"] == 0


def test_health_goes_degraded_down_degraded_up_and_logs_each_change_once(clock, health_log):
    d = DeviceStats(7)
    clock.now += 1
    d.failed()
    assert (d.health, d.consecutive_failures, d.health_since) == ("degraded", 1, clock.now)
    assert health_log() == [   # not "1 of its last 20 requests failed": it never answered
        ("WARNING", "device 7 is degraded: it has not answered yet (1 request without a valid "
                    "reply)")]
    d.failed()
    assert (d.health, d.consecutive_failures) == ("degraded", 2)
    assert len(health_log()) == 1                     # no news: not logged again
    clock.now += 1
    d.failed()
    assert (d.health, d.consecutive_failures, d.health_since) == ("down", 3, clock.now)
    assert health_log()[1:] == [
        ("WARNING", "device 7 is down: 3 requests in a row without a valid reply; its "
                    "requests are refused, but for a probe every 5 s, backing off to 60 s")]
    down_since = clock.now
    for _ in range(5):
        clock.now += 1
        d.failed()
    assert (d.health, d.consecutive_failures, d.health_since) == ("down", 8, down_since)
    assert len(health_log()) == 2                     # still down: never once per failure

    clock.now += 1
    d.answered(3.0, None)
    # answered, but 8 of the last 20 outcomes failed: degraded, not up
    assert (d.health, d.consecutive_failures, d.last_success) == ("degraded", 0, clock.now)
    assert health_log()[2:] == [
        ("WARNING", "device 7 is degraded: 8 of its last 20 requests failed")]
    # the failures leave the window after 20 answers in all, not before
    for _ in range(RECENT_WINDOW - 2):
        d.answered(3.0, None)
    assert d.health == "degraded" and len(health_log()) == 3
    clock.now += 1
    d.answered(3.0, None)
    assert (d.health, d.health_since) == ("up", clock.now)
    assert health_log()[3:] == [("INFO", "device 7 is up: its last 20 requests were answered")]
    d.answered(3.0, None)
    assert len(health_log()) == 4


def test_failures_that_are_not_consecutive_never_make_a_device_down(clock, health_log):
    d = DeviceStats(12)
    for _ in range(10):
        d.failed()
        d.failed()
        d.answered(1.0, None)
    assert d.health == "degraded" and d.consecutive_failures == 0
    assert [m for _, m in health_log()] == [
        "device 12 is degraded: it has not answered yet (1 request without a valid reply)"]


def test_an_exception_reply_is_an_answer(clock):
    """A device that answers with an exception is alive: it counts as a success for health,
    and the exception is counted by its code."""
    d = DeviceStats(11)
    d.failed()
    d.failed()
    d.answered(4.0, 0x02)
    assert d.consecutive_failures == 0 and d.last_success == clock.now
    assert d.replies == 1


def test_exceptions_are_counted_by_code_from_devices_and_from_the_gateway_apart():
    d = DeviceStats(11)
    d.answered(1.0, 0x02)
    d.answered(1.0, 0x02)
    d.answered(1.0, 0x06)
    d.answered(1.0, None)
    d.gateway_exception(0x0B)
    d.gateway_exception(0x0B)
    d.gateway_exception(0x0A)
    assert d.exceptions == {0x02: 2, 0x06: 1}
    assert d.gateway_exceptions == {0x0B: 2, 0x0A: 1}
    snap = d.snapshot()
    assert snap["exceptions"] == {"0x02": 2, "0x06": 1}
    assert snap["gateway_exceptions"] == {"0x0a": 1, "0x0b": 2}
    assert list(snap["gateway_exceptions"]) == ["0x0a", "0x0b"]     # sorted by code
    assert snap["replies"] == 4                 # generated exceptions are not device replies


@pytest.mark.parametrize("latency_ms, bucket", [
    (0.0, "2"), (0.4, "2"), (2.0, "2"),        # an upper bound is inclusive (Prometheus le)
    (2.001, "5"), (5.0, "5"), (9.99, "10"), (10.0, "10"), (10.5, "25"), (99.0, "100"),
    (250.0, "250"), (999.9, "1000"), (2500.0, "2500"), (5000.0, "5000"),
    (5000.5, "+Inf"), (60000.0, "+Inf"),
])
def test_latency_lands_in_the_first_bucket_whose_bound_it_does_not_exceed(latency_ms, bucket):
    d = DeviceStats(1)
    d.answered(latency_ms, None)
    buckets = d.snapshot()["latency_buckets_ms"]
    assert list(buckets) == [*map(str, LATENCY_BUCKETS_MS), "+Inf"]
    assert buckets == {b: int(b == bucket) for b in buckets}


def test_latency_buckets_hold_per_bucket_counts_and_the_sum():
    d = DeviceStats(1)
    for ms in (1.0, 1.5, 3.0, 7.0, 7.5, 7.25, 30000.0):
        d.answered(ms, None)
    snap = d.snapshot()
    assert snap["latency_buckets_ms"] == {"2": 2, "5": 1, "10": 3, "25": 0, "50": 0, "100": 0,
                                          "250": 0, "500": 0, "1000": 0, "2500": 0, "5000": 0,
                                          "+Inf": 1}
    assert snap["latency_sum_ms"] == pytest.approx(30027.25)
    assert sum(snap["latency_buckets_ms"].values()) == snap["replies"] == 7


def test_failures_add_nothing_to_the_latency():
    d = DeviceStats(2)
    d.failed()
    assert sum(d.latency_buckets) == 0 and d.latency_sum_ms == 0 and d.last_success is None


def test_table_creates_a_device_on_first_use_and_lists_them_by_address():
    table = DeviceHealth()
    assert table.all() == []
    a = table.get(17)
    assert table.get(17) is a
    table.get(3)
    table.get(247)
    assert [d.address for d in table.all()] == [3, 17, 247]


def test_reset_zeroes_the_counts_and_keeps_health_and_last_success(clock, health_log):
    table = DeviceHealth()
    d = table.get(5)
    d.transactions = 9
    for name in COUNTS:
        setattr(d, name, 4)
    d.answered(7.0, 0x02)
    d.gateway_exception(0x0B)
    success_at = clock.now
    clock.now += 10
    for _ in range(3):
        d.failed()
    assert d.health == "down"
    logged = len(health_log())

    clock.now += 10
    table.reset()
    r = table.get(5)
    snap = r.snapshot()
    assert {name: snap[name] for name in COUNTS} == dict.fromkeys(COUNTS, 0)
    assert snap["exceptions"] == {} and snap["gateway_exceptions"] == {}
    assert sum(snap["latency_buckets_ms"].values()) == 0 and snap["latency_sum_ms"] == 0
    assert snap["health"] == "down" and snap["health_since"] == success_at + 10
    assert snap["last_success"] == success_at and snap["consecutive_failures"] == 3
    assert len(health_log()) == logged            # a reset is no change of health
    # the recent outcomes survive too: one answer makes it degraded, not up
    r.answered(1.0, None)
    assert r.health == "degraded"
    assert [d.address for d in table.all()] == [5]


def test_reset_is_in_place_so_a_transaction_in_progress_keeps_counting(health_log):
    """The line thread holds its device's object through a transaction while the operator
    resets: the outcome must land in the table, health included."""
    table = DeviceHealth()
    held = table.get(3)
    for _ in range(3):
        held.failed()
    table.reset()
    held.answered(1.0, None)              # the transaction that was in progress
    device = table.get(3)
    assert (device.health, device.replies, device.consecutive_failures) == ("degraded", 1, 0)
    assert [m.split(":")[0] for _, m in health_log()] == [
        "device 3 is degraded", "device 3 is down", "device 3 is degraded"]


def test_every_count_is_a_declared_int_field():
    from mbgw.ops.device_stats import ALL_COUNTS, DeviceStats
    declared = {name for name, kind in DeviceStats.__annotations__.items()
                if kind in (int, "int")}
    assert declared == set(ALL_COUNTS)


# --- demotion: health drives the line -------------------------------------------------------

def rule(down_after: int = 3, probe_interval_ms: int = 1000) -> HealthRule:
    return HealthRule(Demotion(down_after, probe_interval_ms))


def test_down_after_exactly_down_after_failures_and_flagged_for_the_line(clock):
    table = DeviceHealth(rule=rule(down_after=4))
    d = table.get(9)
    for n in range(1, 5):
        assert table.rule.down[9] == 0 and d.admit(clock.monotonic())
        d.failed()
        assert d.health == ("down" if n == 4 else "degraded")
    assert table.rule.down[9] == 1
    assert sum(table.rule.down) == 1
    d.answered(2.0, None)
    assert (d.health, table.rule.down[9]) == ("degraded", 0)


def test_a_down_device_admits_one_probe_per_interval_doubling_while_it_fails(clock):
    """Interval 1 s: the first probe 1 s after going down, then 2, 4, ... up to 60 s (timed
    from the probe's failure); everything between is refused and counted."""
    d = DeviceStats(5, rule=rule(probe_interval_ms=1000))
    for _ in range(3):
        d.failed()
    assert d.health == "down"
    waits = []
    for _ in range(9):
        refused = d.demoted_rejects
        start = clock.now
        while not d.admit(clock.monotonic()):
            clock.now += 0.25
        assert d.demoted_rejects - refused == (clock.now - start) / 0.25
        assert not d.admit(clock.monotonic())      # one probe, not two
        waits.append(clock.now - start)
        d.failed()                                  # the probe failed at once
    assert waits == [1, 2, 4, 8, 16, 32, 60, 60, 60]
    assert d.health == "down" and d.consecutive_failures == 12
    d.answered(1.0, None)                           # the probe after that answers
    assert d.health == "degraded" and d.admit(clock.monotonic())


def test_a_probe_is_due_an_interval_after_the_last_one_even_if_it_never_ended(clock):
    """A probe that never gets its outcome (its client went, say) holds the next back one
    interval, no more."""
    d = DeviceStats(5, rule=rule(probe_interval_ms=1000))
    for _ in range(3):
        d.failed()
    clock.now += 1
    assert d.admit(clock.monotonic())
    clock.now += 0.5
    assert not d.admit(clock.monotonic())
    clock.now += 0.5
    assert d.admit(clock.monotonic())


def test_an_exception_reply_keeps_a_device_from_ever_going_down(clock):
    d = DeviceStats(11, rule=rule(down_after=2))
    for _ in range(10):
        d.failed()
        d.answered(3.0, 0x02)
    assert d.health == "degraded" and d.consecutive_failures == 0
    assert d.admit(clock.monotonic()) and d.demoted_rejects == 0


def test_down_after_0_never_demotes(clock, health_log):
    d = DeviceStats(2, rule=rule(down_after=0))
    for _ in range(50):
        assert d.admit(clock.monotonic())
        d.failed()
    assert (d.health, d.consecutive_failures, d.demoted_rejects) == ("degraded", 50, 0)
    assert [m for _, m in health_log()] == [
        "device 2 is degraded: it has not answered yet (1 request without a valid reply)"]


def test_new_settings_judge_every_device_again_and_log_only_the_changes(clock, health_log):
    table = DeviceHealth(rule=rule(down_after=5, probe_interval_ms=8000))
    a, b = table.get(1), table.get(2)
    for _ in range(3):
        a.failed()
    b.failed()
    assert (a.health, b.health) == ("degraded", "degraded")
    logged = len(health_log())
    table.set_rule(Demotion(3, 8000))
    assert (a.health, b.health, table.rule.down[1]) == ("down", "degraded", 1)
    assert [m.split(":")[0] for _, m in health_log()[logged:]] == ["device 1 is down"]
    clock.now += 7.5
    assert not a.admit(clock.monotonic())
    table.set_rule(Demotion(3, 500))               # a shorter interval: due within it
    assert not a.admit(clock.monotonic())
    clock.now += 0.5
    assert a.admit(clock.monotonic())
    a.failed()
    clock.now += 1                                 # and the backoff starts from it
    assert a.admit(clock.monotonic())
    table.set_rule(Demotion(0, 500))                # demotion off: nothing is down
    assert (a.health, table.rule.down[1]) == ("degraded", 0)
    assert [m.split(":")[0] for _, m in health_log()[logged:]] == [
        "device 1 is down", "device 1 is degraded"]


def test_a_device_that_answered_once_is_degraded_by_its_window(clock, health_log):
    d = DeviceStats(4)
    d.answered(2.0, None)
    d.failed()
    assert [m for _, m in health_log()] == [
        "device 4 is degraded: 1 of its last 20 requests failed"]


# --- demotion, refined (issue 29) ---

def test_down_also_needs_down_after_stouts_without_an_answer(clock):
    """Failures quicker than stout (probes) make no device down before down-after x stout
    has passed since the last answer."""
    d = DeviceStats(4, rule=HealthRule(Demotion(2, 1000), stout_ms=1000))
    d.answered(5.0, None)
    d.failed()
    clock.now += 0.03
    d.failed()
    assert (d.consecutive_failures, d.health) == (2, "degraded")
    clock.now += 1.0                    # 1.03 s + the first failure's stout: 2 stouts
    d.failed()
    assert d.health == "down"


def test_the_probe_timeout_is_3_p99_of_the_last_100_answers_within_20_ms_and_stout(clock):
    d = DeviceStats(4, rule=HealthRule(Demotion(3, 1000), stout_ms=500))
    assert (d.learnt_p99_ms(), d.probe_timeout_ms()) == (None, 500)   # no answer: stout
    for _ in range(100):
        d.answered(2.0, None)
    assert (d.learnt_p99_ms(), d.probe_timeout_ms()) == (2.0, 20)      # at least 20 ms
    for n in range(100):                # the ring keeps the last 100: 1..100 ms
        d.answered(float(n + 1), None)
    assert (d.learnt_p99_ms(), d.probe_timeout_ms()) == (99.0, 297.0)
    for _ in range(100):
        d.answered(400.0, None)
    assert d.probe_timeout_ms() == 500                                 # at most stout


def test_a_device_that_never_answered_waits_the_learnt_time_of_its_line(clock):
    """Before its own first answer a probe waits 3 x the p99 of the line's last 100 answers
    (any device's), within 20 ms and its stout; before any answer on the line, its stout."""
    table = DeviceHealth(rule=HealthRule(Demotion(3, 1000), stout_ms=500))
    silent, slow, quick = table.get(2), table.get(3), table.get(1)
    assert (silent.learnt_p99_ms(), silent.probe_timeout_ms()) == (None, 500)
    for n in range(100):
        quick.answered(float(n % 10 + 1), None)         # 1..10 ms
    assert (silent.learnt_p99_ms(), silent.probe_timeout_ms()) == (None, 30.0)
    for _ in range(50):
        slow.answered(40.0, None)                        # the line's last 100: 50 of them
    assert silent.probe_timeout_ms() == 120.0
    for _ in range(100):
        slow.answered(400.0, None)
    assert silent.probe_timeout_ms() == 500                             # at most stout
    quick.answered(1.0, None)
    assert quick.probe_timeout_ms() == 30.0                             # its own first
    assert DeviceStats(4, rule=HealthRule(Demotion(3, 1000), stout_ms=500)) \
        .probe_timeout_ms() == 500                       # a line of its own: no answer


def test_failures_that_waited_less_than_stout_bring_down_no_sooner(clock):
    """A failure counts as silence what its request waited: the short waits of probes never
    make down-after x stout come sooner."""
    d = DeviceStats(4, rule=HealthRule(Demotion(2, 1000), stout_ms=1000))
    d.failed(waited_ms=30)
    clock.now += 0.03
    d.failed(waited_ms=30)
    assert (d.consecutive_failures, d.health) == (2, "degraded")
    clock.now += 1.9                    # 1.96 s since the first request went
    d.failed(waited_ms=30)
    assert d.health == "degraded"
    clock.now += 0.04
    d.failed(waited_ms=30)
    assert d.health == "down"


def test_with_a_request_kept_the_line_probes_and_every_request_is_refused(clock):
    d = DeviceStats(4, rule=HealthRule(Demotion(3, 1000), stout_ms=100))
    d.probe_adu = b"\x04\x03\x00\x00\x00\x01"
    for _ in range(3):
        d.failed()
        clock.now += 0.1                # each failure took stout
    d.rejudge()
    assert d.health == "down" and d.probe_due(clock.monotonic()) is None
    clock.now += 1
    assert not d.admit(clock.monotonic())           # the client's request is refused ...
    assert d.probe_due(clock.monotonic()) == d.probe_adu    # ... the line thread probes
    assert d.probe_due(clock.monotonic()) is None           # one per interval
    d.failed()
    clock.now += 1.5
    assert d.probe_due(clock.monotonic()) is None           # doubled: 2 s
    clock.now += 0.5
    assert d.probe_due(clock.monotonic()) == d.probe_adu
    d.answered(3.0, None)
    assert d.health == "degraded" and d.probe_due(clock.monotonic()) is None
