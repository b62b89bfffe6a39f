"""What the schema says of each key for the console (mbgw.config.schema.key_help): the
choices of an enumerated key, its unit, its help, the modes it applies to."""
import pytest

from mbgw.cli import main
from mbgw.config import model
from mbgw.config.schema import GROUPS, MODES, Schema, key_help


@pytest.fixture(scope="module")
def keys():
    return Schema(main)


def test_enumerated_keys_offer_their_values(keys):
    assert key_help(keys, "mode").choices == MODES
    assert key_help(keys, "protocol").choices == model.PROTOCOLS
    assert set(key_help(keys, "interface").choices) >= {"rs232", "rs485", "rs422 slave"}
    formats = key_help(keys, "format").choices
    assert len(formats) == 20 and "8n1" in formats and "7e2" in formats
    assert key_help(keys, "exception").choices == ("on", "off")         # a flag
    assert key_help(keys, "stout").choices == ()


def test_every_format_offered_parses():
    for word in key_help(Schema(main), "format").choices:
        assert str(model.LineFormat.parse(word)) == word


def test_units_and_help(keys):
    assert key_help(keys, "stout").unit == "ms"
    assert key_help(keys, "baudrate").unit == "bit/s"
    assert key_help(keys, "device").unit == ""
    assert "restart" in key_help(keys, "mode").help
    assert all(key_help(keys, name).help for group in GROUPS
               for name in keys.group_keys(group))


def test_a_key_names_the_modes_it_applies_to(keys):
    assert key_help(keys, "retries").modes == ("slave",)
    assert key_help(keys, "eof").modes == ("transparent",)
    assert key_help(keys, "device").modes == keys.modes
