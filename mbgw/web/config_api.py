"""The configuration file from the console: read as `mbgw config show` shows it, keys set
with the same checks as `mbgw config set` (several at once, written once), the whole file
downloaded and uploaded (checked as `mbgw check-config` does).  A change is written
atomically, or not at all.

The keys come from the mode commands (mbgw.config.schema), which the CLI hands over with
use_commands() when it starts a daemon: web never imports cli."""
import re
import shlex
import tomllib
from collections.abc import Callable
from pathlib import Path

import click

from mbgw.config import firewall as fw
from mbgw.config import scenario_text
from mbgw.config.array_text import replace_tables
from mbgw.config.edit import REMOVE, apply_changes, changes_for_set, show_lines
from mbgw.config.file import SCENARIO_KEY, Settings, check, load, parse, read_text, resolve
from mbgw.config.line_file import ROUTE_TABLE
from mbgw.config.scenario import parse_scenario
from mbgw.config.schema import GROUPS, MODE_KEY, MODES, Schema, is_secret, key_help
from mbgw.config.text import edit, factory_text
from mbgw.config.toml_text import dump_value, set_line, write_atomic
from mbgw.errors import ConfigError, ConfigFileError, MbgwError

MAX_FILE = 256 * 1024

_root: click.Group | None = None
_given: frozenset = frozenset()
_check: Callable | None = None


def use_commands(root: click.Group, given=(), check: Callable | None = None) -> None:
    """The click group whose mode commands define the keys (mbgw.cli.main), the
    parameters the daemon's command line gave (the file need not have them: a reload keeps
    them), and check(schema, settings, given) -> settings: what `mbgw run` and check-config
    check (mbgw.cli.checks.check_file; raises ConfigFileError)."""
    global _root, _given, _check
    _root, _given, _check = root, frozenset(given), check


def _start_check(keys: Schema, settings: Settings) -> None:
    """Raises ConfigFileError when `mbgw run` (and so a reload) would refuse the file."""
    if _check is not None:
        _check(keys, settings, given=_given)
    else:
        resolve(keys, settings, given=_given)


class ConfigRefused(MbgwError):
    """A change that was not made: why, the key ("group.key", or None) and the problems."""

    def __init__(self, message: str, field: str | None = None, problems=()) -> None:
        super().__init__(message)
        self.field = field
        self.problems = list(problems)


def schema() -> Schema:
    if _root is None:
        raise ConfigRefused("the configuration's keys are unknown to this daemon")
    return Schema(_root)


def show(path: Path) -> dict:
    """{"file", "mode", "groups": {group: {key: {"value", "lines", "help", "unit", "choices",
    "modes"}}}}: the effective value (the file's, else the default) as TOML gives it, as
    `config show` prints it, and what the schema says of the key (mbgw.config.schema.KeyHelp:
    "modes" the modes it applies to)."""
    keys = schema()
    settings = _load(keys, path)
    groups: dict = {}
    for group in GROUPS:
        for name in keys.group_keys(group):
            about = key_help(keys, name)
            groups.setdefault(group, {})[keys.file_name(name)] = {
                "value": settings.get(keys, name),
                "lines": show_lines(keys, settings, name),
                "help": about.help, "unit": about.unit, "choices": list(about.choices),
                "modes": list(about.modes)}
    return {"file": str(path), "mode": settings.mode, "groups": groups}


def set_values(path: Path, wanted: list[tuple[str, str, object]]) -> dict:
    """Several `mbgw config set`s at once, in order: each checked as it does, then the file
    with all of them checked as check-config does, and written once (or not at all).
    Raises ConfigRefused naming the first field refused."""
    keys = schema()
    text = _read(path)
    try:
        data = parse(path, text)
        settings = check(keys, path, data)
    except ConfigFileError as err:
        raise ConfigRefused("the file has problems: fix it first", None, err.problems) \
            from None
    mode = settings.mode
    changes: dict = {}
    field = None
    try:
        for group, key, value in wanted:
            field = f"{group}.{key}"
            words = _settable(keys, group, key, value, mode)
            step = changes_for_set(keys, settings, group, key, words)
            data = apply_changes(data, keys, step)
            settings = check(keys, path, data)
            changes.update(step)
        _start_check(keys, settings)
    except ConfigFileError as err:
        raise ConfigRefused("; ".join(err.problems), field, err.problems) from None
    except ConfigError as err:
        raise ConfigRefused(str(err), field) from None
    new_text = edit(text, keys, changes.get(MODE_KEY, mode), changes)
    if tomllib.loads(new_text) != data:
        raise ConfigRefused("could not edit the file in place; nothing written", field)
    _write(path, new_text)
    return {keys.label(name): (None if v is REMOVE else v)
            for name, v in changes.items() if name not in keys.keys
            or not any(map(is_secret, keys.keys[name].params.values()))}


def _settable(keys: Schema, group: str, key: str, value, mode: str) -> list[str]:
    """The words of a value for group.key; raises ConfigRefused for a password hash and for
    another mode (both have their own way)."""
    field = f"{group}.{key}"
    words = _words(value, field)
    found = keys.find(group, key) if group in GROUPS else None
    if found is not None and any(map(is_secret, found.params.values())):
        raise ConfigRefused(f"{field}: set it with mbgw config password", field)
    if group == "serial" and key == MODE_KEY and words and words[0].lower() in MODES \
            and words[0].lower() != mode:
        raise ConfigRefused(f"{field}: changing the mode needs a restart: use mbgw config set "
                            f"serial mode ... and systemctl restart mbgw", field)
    return words


def set_password(path: Path, role: str, stored: str) -> None:
    """The hash of a role's password written as `mbgw config password ROLE` writes it."""
    keys = schema()
    text = _read(path)
    try:
        data = parse(path, text)
        settings = check(keys, path, data)
        changes = {f"{role}-password": stored}
        data = apply_changes(data, keys, changes)
        _start_check(keys, check(keys, path, data))
    except ConfigFileError as err:
        raise ConfigRefused("the file has problems: fix it first", None, err.problems) \
            from None
    new_text = edit(text, keys, settings.mode, changes)
    if tomllib.loads(new_text) != data:
        raise ConfigRefused("could not edit the file in place; nothing written")
    _write(path, new_text)


def scenario_tables(path: Path) -> list[dict]:
    """The file's [[scenario]] tables as it writes them (the toolbox edits these)."""
    data = _parsed(path, _read(path))
    return [e for e in data.get(SCENARIO_KEY, []) if isinstance(e, dict)]


def edit_scenarios(path: Path, remove: list[str], add: list[dict]) -> list[str]:
    """Scenarios taken out by name, then added (each checked as `mbgw config scenario add`
    checks it; a changed one is taken out and added), the file checked as a whole and
    written once; raises ConfigRefused naming the scenario.  What was done, in words."""
    keys = schema()
    text = _read(path)
    data = _parsed(path, text)
    done = []
    for name in remove:
        new_text = scenario_text.remove(text, name)
        if new_text is None:
            raise ConfigRefused(f"no scenario {name!r}", f"scenario {name}")
        text = new_text
        done.append(f"{name} removed")
    for fields in add:
        name = str(fields.get("name", ""))
        label = f"scenario {name}"
        try:
            scenario = parse_scenario(fields, label)
        except ConfigError as err:
            raise ConfigRefused(str(err), label) from None
        if any(e.get("name") == name for e in
               _parsed(path, text).get(SCENARIO_KEY, []) if isinstance(e, dict)):
            raise ConfigRefused(f"{label}: already there", label)
        text = scenario_text.add(text, scenario.fields())
        done.append(f"{name} {'changed' if name in remove else 'added'}")
    try:
        _start_check(keys, check(keys, path, parse(path, text)))
    except ConfigFileError as err:
        raise ConfigRefused("; ".join(err.problems), None, err.problems) from None
    if data == parse(path, text):
        return []
    _write(path, text)
    return done


def _parsed(path: Path, text: str) -> dict:
    try:
        return parse(path, text)
    except ConfigFileError as err:
        raise ConfigRefused("the file has problems: fix it first", None, err.problems) \
            from None


def firewall_tables(path: Path) -> dict:
    """{"default", "rules": [the file's [[rule]] tables]}."""
    data = _parsed(path, _read(path))
    group = data.get(fw.GROUP, {})
    return {"default": group.get(fw.DEFAULT_KEY, fw.DEFAULT_POLICY)
            if isinstance(group, dict) else fw.DEFAULT_POLICY,
            "rules": [r for r in data.get(fw.RULE_TABLE, []) if isinstance(r, dict)]}


def set_firewall(path: Path, default: str, rules: list[dict]) -> None:
    """[firewall] default and every [[rule]] replaced, in the order given; checked as
    check-config does and written once (or not at all); raises ConfigRefused naming the
    rule."""
    keys = schema()
    text = _read(path)
    _parsed(path, text)
    text = set_line(text, fw.GROUP, fw.DEFAULT_KEY,
                    f"{fw.DEFAULT_KEY} = {dump_value(default)}")
    text = replace_tables(text, fw.RULE_TABLE, rules)
    try:
        _start_check(keys, check(keys, path, parse(path, text)))
    except ConfigFileError as err:
        raise ConfigRefused("; ".join(err.problems), None, err.problems) from None
    _write(path, text)


def route_tables(path: Path) -> list[dict]:
    """The file's [[route]] tables as it writes them (the Lines page edits these)."""
    data = _parsed(path, _read(path))
    return [r for r in data.get(ROUTE_TABLE, []) if isinstance(r, dict)]


def set_routes(path: Path, routes: list[dict]) -> None:
    """Every [[route]] replaced, in the order given; checked as check-config does and written
    once (or not at all); raises ConfigRefused naming the first route key refused."""
    keys = schema()
    text = _read(path)
    _parsed(path, text)
    try:
        text = replace_tables(text, ROUTE_TABLE, routes)
    except TypeError as err:            # a value TOML cannot hold (null, a nested list...)
        raise ConfigRefused(f"route: {err}", ROUTE_TABLE) from None
    try:
        _start_check(keys, check(keys, path, parse(path, text)))
    except ConfigFileError as err:
        raise ConfigRefused("; ".join(err.problems), _route_field(err.problems),
                            err.problems) from None
    _write(path, text)


def _route_field(problems: list[str]) -> str | None:
    """The first route key a problem names ("route 2.units"), for the page to mark."""
    for problem in problems:
        found = _ROUTE_KEY.search(problem)
        if found:
            return found.group(1)
    return None


_ROUTE_KEY = re.compile(r"(route \d+\.[a-z-]+)")


def factory_reset(path: Path) -> None:
    """The file the package ships (`mbgw config default`: every key at its built-in
    default) in place of this one."""
    _write(path, factory_text(schema()))


def read_file(path: Path) -> str:
    return _read(path)


def upload(path: Path, text: str) -> str:
    """Replace the file by `text` when it passes check-config's checks; its mode."""
    keys = schema()
    if len(text.encode()) > MAX_FILE:
        raise ConfigRefused(f"the file is over {MAX_FILE // 1024} KiB")
    try:
        settings = check(keys, path, parse(path, text))
        _start_check(keys, settings)
    except ConfigFileError as err:
        raise ConfigRefused(f"{len(err.problems)} problem(s); nothing written", None,
                            err.problems) from None
    _write(path, text)
    return settings.mode


def _words(value, field: str) -> list[str]:
    if isinstance(value, bool):
        return ["on" if value else "off"]
    if isinstance(value, int):
        return [str(value)]
    if isinstance(value, str):
        try:
            return shlex.split(value)
        except ValueError as err:
            raise ConfigRefused(f"{field}: {err}", field) from None
    if isinstance(value, list) and all(isinstance(w, (str, int)) for w in value):
        return [str(w) for w in value]
    raise ConfigRefused(f"{field}: the value must be a string of words, a number or a flag",
                        field)


def _load(keys: Schema, path: Path) -> Settings:
    try:
        return load(keys, path)
    except ConfigFileError as err:
        raise ConfigRefused("the file has problems", None, err.problems) from None
    except OSError as err:
        raise ConfigRefused(f"cannot read {path}: {err.strerror or err}") from None


def _read(path: Path) -> str:
    try:
        return read_text(path)
    except OSError as err:
        raise ConfigRefused(f"cannot read {path}: {err.strerror or err}") from None


def _write(path: Path, text: str) -> None:
    try:
        write_atomic(path, text)
    except OSError as err:
        raise ConfigRefused(f"cannot write {path}: {err.strerror or err}") from None
