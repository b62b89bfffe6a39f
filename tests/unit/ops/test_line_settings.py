"""A line's row of the status: its settings in the console's words' keys, the time it was
busy in ms, and since when its state holds."""
from mbgw.config.cache import CacheRule
from mbgw.config.lines import LineConfig, RemoteTarget
from mbgw.config.model import Demotion, LineFormat, SerialConfig
from mbgw.ops.status import line_row, settings_row

SERIAL = SerialConfig("/dev/ttyUSB1", baudrate=38400, format=LineFormat(8, "e", 1),
                      stout_ms=250)


def test_a_target_line_s_settings_include_its_timing_and_cache():
    line = LineConfig("beta", SERIAL, retries=2, demotion=Demotion(4, 3000),
                      cache=CacheRule(500, 0))
    assert settings_row(line) == {
        "device": "/dev/ttyUSB1", "protocol": "rtu", "baudrate": 38400, "format": "8e1",
        "interface": "rs232", "silence_ms": 0, "interframe_silence_ms": 0, "stout_ms": 250,
        "retries": 2, "down_after": 4, "probe_interval_ms": 3000,
        "cache": "ttl=500,serve-stale=0"}


def test_a_remote_line_names_its_url_and_no_serial_port():
    line = LineConfig("inverter", SERIAL, remote=RemoteTarget("modbus-tcp", "10.0.0.7", 502),
                      connect_delay_ms=100)
    settings = settings_row(line)
    assert settings["connect"] == "modbus-tcp://10.0.0.7:502"
    assert settings["connect_delay_ms"] == 100 and "baudrate" not in settings


def test_a_line_in_master_mode_has_no_timing_of_a_master():
    settings = settings_row(LineConfig("panel", SERIAL, mode="master"))
    assert "stout_ms" not in settings and settings["baudrate"] == 38400


def test_the_row_carries_busy_ms_and_state_since_and_no_nanoseconds():
    counters = {"requests": 3, "replies": 3, "timeouts": 0, "line_busy_ns": 12_345_678}
    row = line_row("beta", "/dev/ttyUSB1", "slave", "up", counters, [], None, {"retries": 0},
                   1_700_000_000.5)
    assert row["busy_ms"] == 12 and "line_busy_ns" not in row["counters"]
    assert row["state_since"] == 1_700_000_000.5 and row["settings"] == {"retries": 0}
