"""The line's load now (mbgw.ops.load): the busy share of the last 10 s and the last minute,
from the busy-time counter sampled once a second, never above 100 %."""
from mbgw.ops.load import LineLoad, average_percent


class Line:
    def __init__(self) -> None:
        self.now = 1000.0
        self.busy_ns = 0

    def run(self, seconds: int, busy_share: float, load: LineLoad) -> None:
        for _ in range(seconds):
            self.now += 1
            self.busy_ns += int(busy_share * 1e9)
            load.sample()


def test_the_windows_follow_the_load_while_the_average_lags():
    line = Line()
    load = LineLoad(lambda: line.busy_ns, clock=lambda: line.now)
    load.sample()
    line.run(60, 0.1, load)
    assert load.percent() == {"10s": 10.0, "1min": 10.0}
    line.run(10, 0.9, load)
    shares = load.percent()
    assert shares["10s"] == 90.0 and 20.0 < shares["1min"] < 30.0


def test_a_transaction_counted_whole_at_its_end_never_shows_over_100():
    line = Line()
    load = LineLoad(lambda: line.busy_ns, clock=lambda: line.now)
    load.sample()
    line.now += 2
    line.busy_ns += 5 * 10**9          # a long transaction, begun before the window
    assert load.percent() == {"10s": 100.0, "1min": 100.0}
    assert average_percent(5 * 10**9, 2.0) == 100.0 and average_percent(10**9, 4.0) == 25.0


def test_a_reset_of_the_counters_starts_the_windows_again():
    line = Line()
    load = LineLoad(lambda: line.busy_ns, clock=lambda: line.now)
    line.run(20, 0.5, load)
    line.busy_ns = 0
    line.run(5, 0.2, load)
    assert load.percent()["10s"] == 20.0


def test_the_average_is_measured_on_the_monotonic_clock(monkeypatch):
    """A gateway without a battery clock steps its wall clock back at boot (NTP): the
    average since the reset must not jump over 100 % then."""
    import time
    from types import SimpleNamespace

    from mbgw.config.model import SerialConfig, SlaveConfig
    from mbgw.ops.counters import Counters
    from mbgw.ops.device_stats import DeviceHealth
    from mbgw.slave.status import SlaveStatus

    counters = Counters()
    server = SimpleNamespace(trace=None, clients=[], face_figures=dict,
                             firewall=SimpleNamespace(configured=False))
    wall, mono = time.time(), time.monotonic()
    monkeypatch.setattr(time, "monotonic", lambda: mono)          # the reset, dated exactly
    status = SlaveStatus(SlaveConfig(SerialConfig("/dev/null")), server,
                         SimpleNamespace(up=True, state="up", state_since=wall),
                         SimpleNamespace(depth=0), counters, DeviceHealth(), [])
    counters.line_busy_ns = 5 * 10**9
    monkeypatch.setattr(time, "time", lambda: wall - 3600)        # stepped back an hour
    monkeypatch.setattr(time, "monotonic", lambda: mono + 20)
    assert status.status({})["line_utilisation_pct"] == 25.0
