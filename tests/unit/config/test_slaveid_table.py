"""Master mode's slaveid table against the ACKSYS Modbus TCP user guide ("set net slaveid",
syntax in MASTER mode), and the `mbgw master` options that build it."""
import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.config.slaveid import MAX_RANGES, SlaveIdTable, SlaveRange
from mbgw.errors import ConfigError

GUIDE_LINES = ("1 8 1 0 192.168.0.30", "9 16 0 1 192.168.20.0", "17 24 31 1 192.168.50.0")

# Every "Local slave #n directed to IP ... ID field = ..." line of the guide's examples.
GUIDE_ROUTES = {
    1: ("192.168.0.30", 1), 4: ("192.168.0.30", 4), 8: ("192.168.0.30", 8),
    9: ("192.168.20.0", 0xFF), 12: ("192.168.20.3", 0xFF), 16: ("192.168.20.7", 0xFF),
    17: ("192.168.50.0", 31), 19: ("192.168.50.2", 33), 24: ("192.168.50.7", 38),
}


@pytest.fixture
def guide_table() -> SlaveIdTable:
    return SlaveIdTable.parse(GUIDE_LINES)


@pytest.mark.parametrize("address", sorted(GUIDE_ROUTES))
def test_the_guides_examples(guide_table, address):
    assert guide_table.route(address) == GUIDE_ROUTES[address]


def test_addresses_outside_every_range_have_no_route(guide_table):
    assert [a for a in range(256) if guide_table.route(a) is None] == [0, *range(25, 256)]


def test_destinations_are_every_server_once_in_table_order(guide_table):
    assert guide_table.destinations == (
        "192.168.0.30", *(f"192.168.20.{i}" for i in range(8)),
        *(f"192.168.50.{i}" for i in range(8)))


def test_a_line_whose_first_address_is_in_a_range_replaces_it(guide_table):
    table = SlaveIdTable.parse([*GUIDE_LINES, "12 14 5 0 10.0.0.1"])
    assert [(r.first, r.last) for r in table.ranges] == [(1, 8), (17, 24), (12, 14)]
    assert table.route(9) is None and table.route(15) is None
    assert table.route(13) == ("10.0.0.1", 6)


def test_each_replacing_line_takes_the_place_of_the_range_holding_its_first_address():
    table = SlaveIdTable.parse(["1 4 1 0 10.0.0.1", "5 8 1 0 10.0.0.2", "1 2 7 0 10.0.0.3",
                                "2 3 9 0 10.0.0.4"])
    assert [(r.first, r.last, str(r.ip)) for r in table.ranges] == [
        (5, 8, "10.0.0.2"), (2, 3, "10.0.0.4")]


@pytest.mark.parametrize("clear", ["0", "0 0 0 0 0.0.0.0"])
def test_fs_zero_clears_the_table(clear):
    table = SlaveIdTable.parse([*GUIDE_LINES, clear, "30 30 1 0 10.0.0.9"])
    assert [(r.first, r.last) for r in table.ranges] == [(30, 30)]
    assert table.route(1) is None


def test_at_most_eight_ranges():
    lines = [f"{a} {a} 1 0 10.0.0.{a}" for a in range(1, MAX_RANGES + 1)]
    assert len(SlaveIdTable.parse(lines).ranges) == MAX_RANGES
    with pytest.raises(ConfigError, match="at most 8 ranges"):
        SlaveIdTable.parse([*lines, "100 100 1 0 10.0.0.100"])
    # a replacement is not a ninth range
    assert len(SlaveIdTable.parse([*lines, "1 1 3 0 10.0.0.100"]).ranges) == MAX_RANGES


def test_a_range_overlapping_another_from_outside_is_refused():
    with pytest.raises(ConfigError, match="overlap the range 5..10"):
        SlaveIdTable.parse(["5 10 1 0 10.0.0.1", "1 6 1 0 10.0.0.2"])


@pytest.mark.parametrize("line, reason", [
    ("1 8 1 0", "expected 'FS LS FR M IP'"),
    ("1 8 1 0 192.168.0.30 7", "expected 'FS LS FR M IP'"),
    ("a 8 1 0 192.168.0.30", "expected 'FS LS FR M IP'"),
    ("248 250 1 0 192.168.0.30", "first address 248"),
    ("8 1 1 0 192.168.0.30", "last address 1"),
    ("1 248 1 0 192.168.0.30", "last address 248"),
    ("1 8 250 0 192.168.0.30", "remote unit ids 250..257"),
    ("1 8 256 0 192.168.0.30", "remote unit ids"),
    ("1 8 1 2 192.168.0.30", "mode 2"),
    ("1 8 1 0 192.168.0.300", "not an IPv4 address"),
    ("1 8 1 0 ::1", "not an IPv4 address"),
    ("1 8 1 0 0.0.0.0", "cannot be a server's address"),
    ("1 8 1 1 192.168.0.250", r"192.168.0.250 \+ 7 runs past"),
])
def test_invalid_lines_name_the_line_and_the_reason(line, reason):
    with pytest.raises(ConfigError, match=reason) as caught:
        SlaveRange.parse(line)
    assert repr(line) in str(caught.value)


def test_edges_are_accepted():
    r = SlaveRange.parse("240 247 248 1 10.0.0.248")
    assert r.route(247) == ("10.0.0.255", 255)
    assert SlaveRange.parse("1 1 0 0 10.0.0.1").route(1) == ("10.0.0.1", 0xFF)


def test_the_table_reads_like_the_guide(guide_table):
    assert str(guide_table) == ("1..8 -> 192.168.0.30 unit 1..8, "
                                "9..16 -> 192.168.20.0..192.168.20.7 unit 255, "
                                "17..24 -> 192.168.50.0..192.168.50.7 unit 31..38")


# ---- the command line ----

def run_master(*args: str):
    return CliRunner().invoke(main, ["master", "--device", "/dev/null", *args],
                              env={"MBGW_CONFIG": None})


@pytest.mark.parametrize("args, message", [
    (["--slaveid", "1 8 1 0 192.168.0.300"], "not an IPv4 address"),
    (["--slaveid", "5 10 1 0 10.0.0.1", "--slaveid", "1 6 1 0 10.0.0.2"], "overlap"),
    (["--tcpto", "0"], "--tcpto"),
    (["--tcpto", "65536"], "--tcpto"),
    (["--max-connections", "0"], "--max-connections"),
    (["--stout", "100"], "'--stout': applies to slave mode only"),
    (["--nocheck"], "'--nocheck': applies to slave mode only"),
])
def test_bad_options_are_usage_errors(args, message):
    result = run_master(*args)
    assert result.exit_code == 2, result.output
    assert message in result.output


def test_a_device_that_does_not_open_is_a_one_line_fatal_error():
    result = run_master("--slaveid", "1 8 1 0 192.168.0.30")      # /dev/null: no tty
    assert result.exit_code == 1
    assert "mbgw: cannot open /dev/null" in result.output
