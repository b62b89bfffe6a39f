"""`mbgw status` shows each line's read cache by unit (issue 27), and nothing for a line
whose cache has not served."""
from mbgw.cli.render import format_status
from mbgw.config.cache import CacheRule
from mbgw.ops.status import line_row
from mbgw.routing.cache import ReadCache

NOW = 1_700_000_000.0


def status(lines: list[dict]) -> dict:
    return {"version": "1.0", "mode": "slave", "pid": 42, "uptime_s": 5.0,
            "listening": ["0.0.0.0:502"],
            "serial": {"device": "/dev/ttyUSB0", "baudrate": 9600, "format": "8n1",
                       "protocol": "rtu", "interface": "rs232", "stout_ms": 600,
                       "state": "up"},
            "queue_depth": 0, "line_utilisation_pct": 0.0, "clients": [], "devices": [],
            "counters": {"requests": 3}, "counters_since": NOW, "lines": lines}


def row(cache: ReadCache) -> dict:
    counters = {"requests": 3, "replies": 3, "timeouts": 0}
    return line_row("serial", "/dev/ttyUSB0", "slave", "up", counters, [], cache.status())


def test_a_line_s_cache_figures_by_unit():
    cache = ReadCache()
    adu = bytes((5, 3, 0, 0, 0, 2))
    cache.missed(adu)
    cache.answered(adu, bytes((3, 4, 0, 1, 0, 2)), 100)
    cache.answer(CacheRule(), adu, 50, 200)           # arrived while it was on the line
    text = format_status(status([row(cache)]), NOW)
    assert "cache      line          unit      hits  coalesced   misses  stale" in text
    assert "           serial           5         0          1        1      0" in text


def test_no_section_for_a_line_whose_cache_never_served():
    assert "cache      line" not in format_status(status([row(ReadCache())]), NOW)
    assert "cache" not in row(ReadCache())
