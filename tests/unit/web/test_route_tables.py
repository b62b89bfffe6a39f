"""The Lines page's routes written to the file: every [[route]] replaced at once, checked
as check-config does, or nothing written and the first key refused named."""
import pytest

from mbgw.cli import main
from mbgw.cli.checks import check_file
from mbgw.web import config_api

FILE = """# the plant's gateway
[serial]
device = "/dev/ttyUSB0"

[[line]]
name = "beta"
device = "/dev/ttyUSB1"

[[route]]
units = "1-4"
line = "serial"
"""


@pytest.fixture
def path(tmp_path):
    config_api.use_commands(main, (), check_file)
    file = tmp_path / "mbgw.toml"
    file.write_text(FILE)
    return file


def test_the_routes_are_replaced_in_order_and_the_rest_of_the_file_kept(path):
    config_api.set_routes(path, [
        {"units": "1-4", "line": "serial"},
        {"units": "5", "line": "beta", "offset": 2, "cache": {"ttl": 500}},
        {"units": "6", "line": "beta", "cache": False}])
    assert config_api.route_tables(path) == [
        {"units": "1-4", "line": "serial"},
        {"units": "5", "line": "beta", "offset": 2, "cache": {"ttl": 500}},
        {"units": "6", "line": "beta", "cache": False}]
    assert path.read_text().startswith("# the plant's gateway\n[serial]")


@pytest.mark.parametrize("routes, field", [
    ([{"units": "1-4", "line": "serial"}, {"units": "3-6", "line": "beta"}], "route 2.units"),
    ([{"units": "1-4", "line": "nowhere"}], "route 1.line"),
    ([{"units": "1-4", "line": "serial", "offset": 999}], "route 1.offset"),
])
def test_a_refused_route_names_its_key_and_writes_nothing(path, routes, field):
    with pytest.raises(config_api.ConfigRefused) as refused:
        config_api.set_routes(path, routes)
    assert refused.value.field == field, refused.value
    assert path.read_text() == FILE


def test_a_value_toml_cannot_hold_is_refused(path):
    with pytest.raises(config_api.ConfigRefused, match="route"):
        config_api.set_routes(path, [{"units": "1-4", "line": None}])
    assert path.read_text() == FILE
