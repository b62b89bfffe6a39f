"""A line's timing by serial address (mbgw.slave.device_timing.DeviceTiming) and each
device's own demotion (DeviceHealth.set_rule's `own`): the line's values but for the units
of its [[device]] tables."""
from mbgw.config.lines import DeviceConfig
from mbgw.config.model import Demotion, SerialConfig, SlaveConfig
from mbgw.ops.device_stats import DOWN, DeviceHealth
from mbgw.slave.device_timing import DeviceTiming

FAST = DeviceConfig(1, 5, stout_ms=50, pause_ms=20, down_after=1)
SLOW = DeviceConfig(2, 9, stout_ms=900, retries=2)
OTHER_LINE = DeviceConfig(3, 7, line="meters", stout_ms=10)


def cfg(**changes) -> SlaveConfig:
    return SlaveConfig(serial=SerialConfig("/dev/ttyUSB0", stout_ms=1000), retries=1,
                       devices=(FAST, SLOW, OTHER_LINE), **changes)


def test_each_address_has_the_lines_timing_but_its_own_devices():
    timing = DeviceTiming.of_line(cfg(), "serial")
    assert timing.stout_ns[5] == 50_000_000 and timing.stout_ns[9] == 900_000_000
    assert timing.stout_ns[7] == timing.stout_ns[1] == 1_000_000_000
    assert (timing.retries[5], timing.retries[9], timing.retries[1]) == (1, 2, 1)
    assert (timing.pause_us[5], timing.pause_us[9]) == (20_000, 0)
    assert [a for a in range(256) if timing.flags[a]] == [5, 9]
    assert (timing.longest_stout_ms, timing.most_retries, timing.longest_pause_ms) == \
        (1000, 2, 20)


def test_a_devices_stout_is_its_late_window_unless_late_window_is_set():
    assert DeviceTiming.of_line(cfg(), "serial").late_window_ns[5] == 50_000_000
    set_ = DeviceTiming.of_line(cfg(late_window_ms=300), "serial")
    assert set_.late_window_ns[5] == set_.late_window_ns[1] == 300_000_000


def test_a_device_goes_down_by_its_own_rule_and_shows_its_timing():
    devices = DeviceHealth()
    line = Demotion(down_after=3, probe_interval_ms=5000)
    devices.set_rule(line, DeviceTiming.of_line(cfg(), "serial").demotions(line))
    assert [d.address for d in devices.all()] == [5, 9]     # listed before any request
    devices.get(5).failed()
    devices.get(6).failed()
    assert (devices.get(5).health, devices.get(6).health) == (DOWN, "degraded")
    assert devices.rule.down[5] == 1
    assert devices.get(5).snapshot()["timing"] == {
        "stout_ms": 50, "retries": 1, "pause_ms": 20, "down_after": 1,
        "probe_interval_ms": 5000}
    assert "timing" not in devices.get(6).snapshot()


def test_a_reload_without_the_device_gives_it_the_lines_rule_again():
    devices = DeviceHealth()
    line = Demotion(down_after=3)
    devices.set_rule(line, DeviceTiming.of_line(cfg(), "serial").demotions(line))
    devices.get(5).failed()
    devices.set_rule(line, {})
    stats = devices.get(5)
    assert stats.rule is devices.rule and stats.health != DOWN and stats.timing is None
    assert devices.rule.down[5] == 0
