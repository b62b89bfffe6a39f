"""The `cache` key (issue 27): per line ([serial], [[line]]) and per route, where a route's
wins and `cache = false` turns it off; refused on a route to the table or a server, and out
of range, each naming its key (check-config exit 78)."""

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.config.cache import CacheRule, parse_cache
from mbgw.errors import ConfigError
from mbgw.routing.cache import resolve
from tests.unit.config.config_files import SERIAL, built, refusal

METERS = '[[line]]\nname = "meters"\ndevice = "/dev/ttyUSB1"\n'


def test_line_serial_and_a_line_take_their_cache(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + 'cache = { ttl = 500, serve-stale = 5000 }\n'
                + METERS + 'cache = { ttl = 100 }\n')
    assert cfg.cache == CacheRule(500, 5000)
    assert cfg.lines[0].cache == CacheRule(100, 0)


def test_without_the_key_there_is_no_cache(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + METERS)
    assert cfg.cache is None and cfg.lines[0].cache is None


def test_a_route_s_cache_replaces_the_line_s_and_false_turns_it_off(schema, tmp_path):
    cfg = built(schema, tmp_path, SERIAL + METERS + 'cache = { ttl = 100, serve-stale = 900 }\n'
                '[[route]]\nunits = "1-9"\nline = "meters"\ncache = { ttl = 40 }\n'
                '[[route]]\nunits = "10-19"\nline = "meters"\ncache = false\n'
                '[[route]]\nunits = "20-29"\nline = "meters"\n')
    line = cfg.lines[0].cache
    own, off, inherited = (r.cache for r in cfg.routes)
    assert resolve(own, line) == CacheRule(40, 0)      # whole: no serve-stale of the line's
    assert resolve(off, line) is None
    assert resolve(inherited, line) == CacheRule(100, 900)


@pytest.mark.parametrize("target", ['table = true', 'server = "192.0.2.1"'])
def test_a_cache_on_a_route_to_the_table_or_a_server_is_refused(tmp_path, target):
    output = refusal(tmp_path, SERIAL + '[table]\nenabled = true\n'
                     f'[[route]]\nunits = "1-9"\n{target}\ncache = {{ ttl = 40 }}\n')
    assert "route 1.cache" in output


@pytest.mark.parametrize("value, said", [
    ("{ ttl = 3600001 }", "out of range 0..3600000"),
    ("{ ttl = -1 }", "out of range"),
    ("{ tll = 5 }", "unknown key 'tll'"),
    ("{ ttl = \"5\" }", "expected an integer"),
    ("500", "expected a table"),
])
def test_bad_values_name_the_key(tmp_path, value, said):
    output = refusal(tmp_path, SERIAL + METERS + f'cache = {value}\n')
    assert "line meters.cache" in output and said in output
    output = refusal(tmp_path, SERIAL + METERS
                     + f'[[route]]\nunits = "1-9"\nline = "meters"\ncache = {value}\n')
    assert "route 1.cache" in output and said in output


def test_the_command_line_spelling():
    assert parse_cache("ttl=500,serve-stale=5000") == CacheRule(500, 5000)
    assert parse_cache("off") is None
    with pytest.raises(ConfigError):
        parse_cache("ttl")


def test_config_show_and_set_write_the_key_as_toml(schema, tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(SERIAL + 'cache = { ttl = 500, serve-stale = 5000 }\n'
                    + METERS + 'cache = { ttl = 100 }\n')
    runner = CliRunner()
    shown = runner.invoke(main, ["config", "show", "--config", str(path), "serial"])
    assert "{ ttl = 500, serve-stale = 5000 }" in shown.output, shown.output
    shown = runner.invoke(main, ["config", "show", "--config", str(path), "line"])
    assert "cache = { ttl = 100 }" in shown.output, shown.output
    result = runner.invoke(main, ["config", "set", "--config", str(path), "serial", "cache",
                                  "ttl=20,serve-stale=40"])
    assert result.exit_code == 0, result.output
    assert built(schema, tmp_path, path.read_text()).cache == CacheRule(20, 40)
