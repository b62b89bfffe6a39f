"""An array of tables replaced as text (mbgw.config.array_text): the others, comments and
groups kept, the new tables at the end in order."""
import tomllib

from mbgw.config.array_text import replace_tables

FILE = """# the gateway
[serial]
stout = 700   # slow meters

[[rule]]
client = "10.0.0.0/8"
read-only = true

[[scenario]]
name = "boiler"

[[rule]]
role = "operator"
"""


def test_every_table_is_replaced_and_the_rest_kept():
    text = replace_tables(FILE, "rule", [{"client": ["127.0.0.1"], "units": "1-10"},
                                          {"read-only": True}])
    data = tomllib.loads(text)
    assert data["rule"] == [{"client": ["127.0.0.1"], "units": "1-10"}, {"read-only": True}]
    assert data["scenario"] == [{"name": "boiler"}] and data["serial"] == {"stout": 700}
    assert text.startswith("# the gateway\n") and "stout = 700   # slow meters" in text


def test_no_tables_left_and_none_there():
    assert "rule" not in tomllib.loads(replace_tables(FILE, "rule", []))
    assert replace_tables("[serial]\nstout = 1\n", "rule", []) == "[serial]\nstout = 1\n"
