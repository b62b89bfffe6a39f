"""mbgw.toml(5) (docs/mbgw.toml.5) documents every key of the configuration file, and no
other, in its group's section: the keys are the options of `mbgw slave` and `mbgw master`
(mbgw.config.schema), so a new option, a changed default, range or choice that the page does
not follow fails here.  Each key's entry is a `.TP` paragraph opened by `.B KEY`."""
import re
import tomllib

import click
import pytest

from mbgw.cli import main
from mbgw.config import firewall
from mbgw.config.schema import GROUPS, MODE_KEY, MODES, Schema, default_value
from mbgw.config.toml_text import dump_value
from tests.harness import CHECKOUT

PAGE = CHECKOUT / "docs" / "mbgw.toml.5"
SCHEMA = Schema(main)


def _entries() -> dict[str, dict[str, str]]:
    """{group: {key: the text of its entry, roff hyphens unescaped}} from the sections
    titled [GROUP]."""
    groups = {}
    for section in re.split(r"^\.SH ", PAGE.read_text(), flags=re.M)[1:]:
        title, _, body = section.partition("\n")
        title = title.strip('"')
        if not title.startswith("["):
            continue
        entries = {}
        for entry in re.split(r"^\.TP\n", body, flags=re.M)[1:]:
            first, _, text = entry.partition("\n")
            opening = re.fullmatch(r"\.B (\S+)", first)
            assert opening, f"{PAGE}: an entry of {title} opens with {first!r}, not .B KEY"
            name = opening.group(1).replace("\\-", "-")
            entries[name] = text.replace("\\-", "-")
        groups[title.strip("[]")] = entries
    return groups


ENTRIES = _entries()
# the firewall's tables (mbgw.config.firewall), which are no options: their sections follow
FIREWALL_TABLES = {firewall.GROUP: firewall.GROUP_KEYS, firewall.RULE_TABLE: firewall.RULE_KEYS}


def test_the_firewall_tables_list_their_keys():
    for table, keys in FIREWALL_TABLES.items():
        assert tuple(ENTRIES[table]) == keys, table


KEYS = [(group, SCHEMA.file_name(name)) for group in GROUPS for name in SCHEMA.group_keys(group)]


def test_every_group_lists_its_keys_in_the_factory_files_order():
    assert list(ENTRIES) == [*GROUPS, *FIREWALL_TABLES]
    for group in GROUPS:
        assert list(ENTRIES[group]) == list(map(SCHEMA.file_name, SCHEMA.group_keys(group))), \
            group


@pytest.mark.parametrize("group, name", KEYS)
def test_each_key_states_its_default_range_choices_and_modes(group, name):
    text = ENTRIES[group][name]
    if name == MODE_KEY:
        assert f'Default \\fB"{SCHEMA.default_mode}"\\fR' in text
        assert all(f"\\fB{mode}\\fR" in text for mode in MODES)
        return
    key = SCHEMA.find(group, name)
    for mode, param in key.params.items():
        default = default_value(SCHEMA, key.name, mode)
        if default is None:
            assert text.startswith("Not set by default"), (name, text)
        else:
            assert f"\\fB{dump_value(default)}\\fR" in text, (name, mode, default)
        for low, high in _ranges(param.type):
            assert f"{low}..{high}" in text, (name, mode)
        if isinstance(param.type, click.Choice):
            for choice in param.type.choices:
                assert f'\\fB"{choice}"\\fR' in text, (name, choice)
    if len(key.params) == 1:
        only = next(iter(key.params))
        assert f"{only.capitalize()} mode only." in text, name


def _ranges(kind: click.ParamType):
    """(min, max) of an IntRange, or of each IntRange of a tuple type."""
    if isinstance(kind, click.IntRange):
        yield kind.min, kind.max
    for part in getattr(kind, "types", ()):
        yield from _ranges(part)


def test_the_examples_are_files_that_check():
    from mbgw.config import file as config_file

    examples = PAGE.read_text().split('.SH EXAMPLES\n', 1)[1].split("\n.SH ", 1)[0]
    files = re.findall(r"^\.nf\n(.*?)^\.fi$", examples, flags=re.M | re.S)
    assert len(files) == 2
    modes = []
    for text in files:
        settings = config_file.check(SCHEMA, PAGE, tomllib.loads(text.replace("\\-", "-")))
        config_file.resolve(SCHEMA, settings)
        modes.append(settings.mode)
    assert sorted(modes) == ["master", "slave"]
