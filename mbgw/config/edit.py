"""The ACKSYS guide's `set` syntax on the configuration file: `set GROUP PARAM VALUE...` as
changes to its keys (the authip entries, the slaveid table's replace-the-oldest rule of
mbgw.config.slaveid, "on" for true, ...), and the keys' values back in the guide's words."""
import ipaddress

import click

from mbgw.config.file import Settings
from mbgw.config.schema import (
    AUTHIP_ENTRIES,
    MODE_KEY,
    MODE_TABLES,
    MODES,
    NO_ADDRESS,
    NOT_SUPPORTED,
    PROTOCOL_KEY,
    PROTOCOL_WORDS,
    Key,
    Schema,
    is_secret,
)
from mbgw.config.slaveid import SlaveIdTable
from mbgw.config.toml_text import dump_value, dumpable
from mbgw.config.values import Problem, element_kinds, process
from mbgw.errors import ConfigError

JOIN_WORDS = {"format": "", "units": ",", "functions": ","}   # "format 8 e 1" is 8e1
REMOVE = object()                          # a change that takes a key out of the file


def changes_for_set(schema: Schema, settings: Settings, group: str, name: str,
                    words: list[str]) -> dict:
    """`set GROUP PARAM VALUE...` as {key: new value} (a value of REMOVE takes the key out).
    Raises ConfigError naming the key and the reason; the new file is checked afterwards."""
    name = name.lower()
    if group == "serial" and name == MODE_KEY:
        return _set_mode(schema, settings, words)
    key = schema.find(group, name)
    if key is None:
        elsewhere = schema.keys.get(name)
        if elsewhere is not None and elsewhere.file_name == name:
            raise ConfigError(f"{group}.{name}: belongs in [{elsewhere.group}]: mbgw config "
                              f"set {elsewhere.group} {name} ...")
        if (group, name) in NOT_SUPPORTED:
            raise ConfigError(f"{group}.{name}: {NOT_SUPPORTED[group, name]}")
        raise ConfigError(f"{group}.{name}: unknown key{schema.hint(name)}")
    name = key.name
    if not words:
        raise ConfigError(f"{key.label}: expected a value")
    param = key.params[key.mode_for(settings.mode)]
    if name == "authip" and param.multiple:
        return {name: _set_authip(settings.values.get(name, []), words)}
    if name == "slaveid" and param.multiple:
        return {name: _set_slaveid_table(settings.values.get(name, []), words)}
    if name == "slaveid" and len(words) == 5:
        raise ConfigError(f"{key.label}: in {settings.mode} mode, one serial address (the table "
                          f"FS LS FR M IP is master mode's: mbgw config set serial mode master)")
    value = _value_from_words(key, param, words)
    return {name: _canonical(schema.commands[key.mode_for(settings.mode)], param, value)}


def _canonical(command: click.Command, param: click.Parameter, value):
    """A string value as its option prints it back ("8E1" -> "8e1", "RS485  echo" ->
    "rs485 echo"), when that means the same to the option."""
    if not isinstance(value, str):
        return value
    try:
        converted = process(command, param, value)
        text = converted if isinstance(converted, str) else str(converted)
        if text != value and process(command, param, text) == converted:
            return text
    except Problem:
        pass                          # the check of the new file will say what is wrong
    return value


def _set_mode(schema: Schema, settings: Settings, words: list[str]) -> dict:
    if len(words) != 1:
        raise ConfigError(f"serial.{MODE_KEY}: expected one of {', '.join(MODES)}, "
                          f"{', '.join(PROTOCOL_WORDS)}")
    word = words[0].lower()
    if word in PROTOCOL_WORDS and PROTOCOL_KEY in schema.keys:
        return {PROTOCOL_KEY: word}
    if word not in schema.modes:
        available = ", ".join((*schema.modes, *PROTOCOL_WORDS))
        reason = "is not in this mbgw" if word in MODES else "is not a mode"
        raise ConfigError(f"serial.{MODE_KEY}: {word!r} {reason} (expected {available})")
    changes: dict[str, object] = {MODE_KEY: word}
    if word != settings.mode:
        changes.update({table: REMOVE for table in MODE_TABLES if table in settings.values})
    return changes


def _set_authip(table: list, words: list[str]) -> list:
    usage = (f"expected an entry 1..{AUTHIP_ENTRIES} and an IP address ({NO_ADDRESS} clears "
             f"the entry), e.g. mbgw config set net authip 1 192.168.1.5")
    if len(words) != 2 or not words[0].isdigit() or not 1 <= int(words[0]) <= AUTHIP_ENTRIES:
        raise ConfigError(f"net.authip: {usage}")
    entry = int(words[0])
    try:
        address = ipaddress.ip_address(words[1])
    except ValueError:
        raise ConfigError(f"net.authip[{entry}]: {words[1]!r} is not an IP address") from None
    table = [*table, *[NO_ADDRESS] * (entry - len(table))]
    table[entry - 1] = str(address)
    while table and table[-1] == NO_ADDRESS:
        table.pop()
    return table


def _set_slaveid_table(table: list, words: list[str]) -> list:
    """The guide: "any slaveid command line with an fs parameter included in a range already
    defined will invalidate and replace the oldest. fs = 0 clears the whole table." """
    try:
        ranges = SlaveIdTable.parse([*table, " ".join(words)]).ranges
    except ConfigError as err:
        raise ConfigError(f"net.slaveid: {err}") from None
    return [r.line() for r in ranges]


def _word_value(kind: str, word: str, label: str):
    try:
        if kind == "bool":
            return click.BOOL.convert(word, None, None)
        if kind == "int":
            return int(word)
        if kind == "float":
            return float(word)
    except (ValueError, click.BadParameter):
        wanted = {"bool": "on or off", "int": "an integer", "float": "a number"}[kind]
        raise ConfigError(f"{label}: expected {wanted}, got {word!r}") from None
    return word


def _value_from_words(key: Key, param: click.Parameter, words: list[str]):
    """The guide's words as the TOML value to write: "on" -> true, "0 0" -> [0, 0], ..."""
    kinds = element_kinds(param)
    if param.multiple:
        return [_word_value(kinds[0], w, key.label) if param.nargs == 1 else w for w in words]
    if param.nargs != 1:
        if len(words) != param.nargs:
            raise ConfigError(f"{key.label}: expected {param.nargs} values, got {len(words)}")
        return [_word_value(k, w, key.label) for k, w in zip(kinds, words, strict=True)]
    if kinds[0] in ("bool", "int", "float"):
        if len(words) != 1:
            raise ConfigError(f"{key.label}: expected one value, got {' '.join(words)!r}")
        return _word_value(kinds[0], words[0], key.label)
    return JOIN_WORDS.get(key.name, " ").join(words)


def apply_changes(data: dict, schema: Schema, changes: dict) -> dict:
    """The parsed file with the changes made (a new dict)."""
    new = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for name, value in changes.items():
        group, written = schema.place(name)
        content = new.setdefault(group, {})
        if value is REMOVE:
            content.pop(written, None)
        else:
            content[written] = value
    return new


TABLE_SWITCH = "table.enabled"


def show_lines(schema: Schema, settings: Settings, name: str) -> list[str]:
    """A key's effective value as `mbgw config show` prints it, in the guide's words: one
    line per table entry, on/off for a flag."""
    value = settings.get(schema, name)
    if name in schema.keys and any(map(is_secret, schema.keys[name].params.values())):
        return ["(set)" if value else "(not set)"]
    if name == "authip" and isinstance(value, list):
        return [f"{i} {a}" for i, a in enumerate(value, 1) if a != NO_ADDRESS] \
            or ["(empty: any client may connect)"]
    key = schema.keys.get(name)
    param = key.params[key.mode_for(settings.mode)] if key else None
    if param is not None and param.multiple:
        return [" ".join(map(str, v)) if isinstance(v, list) else str(v) for v in value] \
            or ["(empty)"]
    if isinstance(value, bool):
        if not value and settings.scenarios and schema.label(name) == TABLE_SWITCH:
            return ["on (scenarios)"]       # they need it: it runs, for them alone
        return ["on" if value else "off"]
    if isinstance(value, list):
        return [" ".join(map(str, value))]
    if isinstance(value, dict) and dumpable(value):     # an inline table (`cache`)
        return [dump_value(value)]
    return ["(not set)" if value is None else str(value)]
