"""The arrays of tables of the configuration file ([[line]], [[route]], [[rule]]): read as a
list of tables, each table checked on its own, and every problem named by the table's place
and key (`route 2.units`, `rule 1.read-only`)."""
import difflib
from collections.abc import Callable
from typing import TypeVar

from mbgw.errors import ConfigError

T = TypeVar("T")


def array_of_tables(data: dict, name: str, problems: list[str],
                    wrong: str | None = None) -> list[dict]:
    """The [[name]] tables of a parsed file ([] when there are none).  When `name` is
    something else: [] and a problem, `wrong` or else "name: expected [[name]] tables"."""
    found = data.get(name, [])
    if not isinstance(found, list) or not all(isinstance(t, dict) for t in found):
        problems.append(wrong or f"{name}: expected [[{name}]] tables")
        return []
    return found


def parse_each(found: list[dict], parse: Callable[[int, dict], T]
               ) -> tuple[tuple[T, ...], list[str]]:
    """parse(index, table) of each table, the index from 1; what it refuses (ConfigError) is
    one problem of that table, and the others are still parsed."""
    parsed: list[T] = []
    problems: list[str] = []
    for index, table in enumerate(found, 1):
        try:
            parsed.append(parse(index, table))
        except ConfigError as err:
            problems.append(str(err))
    return tuple(parsed), problems


def check_keys(label: str, table: dict, keys: tuple[str, ...]) -> None:
    """ConfigError for the first key of `table` not in `keys`: the keys there are, and the
    closest as a hint."""
    for name in table:
        if name not in keys:
            match = difflib.get_close_matches(name.lower(), keys, n=1, cutoff=0.6)
            raise ConfigError(f"{label}.{name}: unknown key (keys: {', '.join(keys)})"
                              + (f"; did you mean {match[0]}?" if match else ""))


def typed(label: str, table: dict, name: str, kind: type, wanted: str, default=None):
    """The table's value of key `name` (`default` when it has none); ConfigError when it is
    not a `kind` (a boolean is no integer), saying what was `wanted`."""
    value = table.get(name, default)
    if value is not default and (not isinstance(value, kind)
                                 or (kind is int and isinstance(value, bool))):
        raise ConfigError(f"{label}.{name}: expected {wanted}, got {value!r}")
    return value
