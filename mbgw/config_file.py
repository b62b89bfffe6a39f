"""The configuration file, /etc/mbgw/mbgw.toml (`mbgw@NAME` reads /etc/mbgw/NAME.toml).

It holds every option of both modes under its ACKSYS name, grouped like the ACKSYS guide:
[serial] (mode, device, baudrate, format, stout, ...), [net] (slaveid, authip, mdbport, tcpto,
...) and [general] (what the guide has no command for).  The keys are not listed here: they are
the long options of the mode commands (`mbgw slave`, `mbgw master`), walked at run time, so an
option added to a command is a key at once.  A value is checked by its option's own click type
and callback, and reaches the command through click's default_map: command line > file >
built-in default.  Changes go through `mbgw config set` (the guide's `set` syntax), which edits
the text in place so that comments survive, and replaces the file atomically."""
import copy
import dataclasses
import difflib
import ipaddress
import textwrap
import tomllib
from pathlib import Path

import click

from mbgw.errors import ConfigError, ConfigFileError
from mbgw.slaveid_table import SlaveIdTable, SlaveRange
from mbgw.toml_edit import dump_value, dumpable, set_line

DEFAULT_PATH = Path("/etc/mbgw/mbgw.toml")
CONFIG_DIR = DEFAULT_PATH.parent           # the instance mbgw@NAME reads CONFIG_DIR/NAME.toml
MODES = ("slave", "master")                # "set serial mode slave|master"
MODE_KEY = "mode"                          # in [serial]; selects the command `mbgw run` starts
PROTOCOL_KEY = "protocol"                  # "set serial mode rtu|ascii" sets it
PROTOCOL_WORDS = ("rtu", "ascii")
GROUPS = ("serial", "net", "general")
# [serial]: the options of mbgw.cli.serial_options (both modes' line settings, found at run
# time) and the slave mode's line behaviour below; [net]: the guide's "set net ..." commands and
# our network options; [general]: the rest (logging, control socket, metrics, ...).
LINE_KEYS = frozenset({"retries", "turnaround"})
NET_KEYS = frozenset({"slaveid", "authip", "mdbport", "tcpto", "exception", "metric", "bind",
                      "max-connections"})
MODE_TABLES = ("authip", "slaveid")        # cleared when the mode changes (the guide says so)
AUTHIP_ENTRIES = 8                         # "n: table entry index, from 1 to 8"
NO_ADDRESS = "0.0.0.0"                     # "IP address 0.0.0.0 clears the entry"
FACTORY_MODE = "slave"
FACTORY_DEVICE = "/dev/ttyUSB0"
JOIN_WORDS = {"format": ""}                # "set serial format 8 e 1" is 8e1
OWN_OPTIONS = frozenset({"config"})        # the option naming the file is not a key
_REMOVE = object()                         # a change that takes a key out of the file


# --- the keys, from the click commands -------------------------------------------------------

@dataclasses.dataclass
class Key:
    name: str                  # the ACKSYS spelling: the option's long flag without "--"
    group: str
    params: dict               # mode -> its click.Option (one per mode command that has it)

    def mode_for(self, mode: str) -> str:
        """The mode whose option checks this key: the file's mode when it has the key."""
        return mode if mode in self.params else next(iter(self.params))

    @property
    def label(self) -> str:
        return f"{self.group}.{self.name}"


class Schema:
    """The keys of the mode commands of `root` (a click group), in [serial], [net], [general]
    order, each group in the commands' option order."""

    def __init__(self, root: click.Group) -> None:
        self.root = root
        self.commands = {m: root.commands[m] for m in MODES if m in root.commands}
        if not self.commands:
            raise RuntimeError(f"{root.name} has no mode command ({', '.join(MODES)})")
        self.modes = tuple(self.commands)
        serial = serial_option_keys() | LINE_KEYS
        found: dict[str, Key] = {}
        for mode, command in self.commands.items():
            for param in command.params:
                name = option_key(param)
                if name is not None:
                    group = "net" if name in NET_KEYS else "serial" if name in serial \
                        else "general"
                    found.setdefault(name, Key(name, group, {})).params[mode] = param
        self.keys = {k.name: k for g in GROUPS for k in found.values() if k.group == g}

    @property
    def default_mode(self) -> str:
        return FACTORY_MODE if FACTORY_MODE in self.modes else self.modes[0]

    def group_keys(self, group: str) -> list[str]:
        names = [k.name for k in self.keys.values() if k.group == group]
        return [MODE_KEY, *names] if group == "serial" else names

    def label(self, name: str) -> str:
        return f"serial.{MODE_KEY}" if name == MODE_KEY else self.keys[name].label

    def hint(self, name: str) -> str:
        """'; did you mean net.authip?' for a misspelt key, else ''."""
        names = [MODE_KEY, *self.keys]
        match = difflib.get_close_matches(name.lower(), names, n=1, cutoff=0.6)
        return f"; did you mean {self.label(match[0])}?" if match else ""

    def key_of_param(self, param: click.Parameter) -> Key | None:
        name = option_key(param)
        return self.keys.get(name) if name else None


def option_key(param: click.Parameter) -> str | None:
    """The configuration key of a command option: its long flag without the dashes."""
    if not isinstance(param, click.Option) or not param.expose_value or param.hidden \
            or param.name in OWN_OPTIONS:
        return None
    longs = [o for o in param.opts if o.startswith("--")]
    return longs[0][2:] if longs else None


def serial_option_keys() -> frozenset:
    """The keys of the serial-line options both mode commands share (mbgw.cli.serial_options,
    the decorator stack that adds them), so that a new serial option is in [serial] at once."""
    from mbgw.cli import serial_options
    params = getattr(serial_options(lambda: None), "__click_params__", [])
    return frozenset(filter(None, map(option_key, params)))


def _is_unset(value) -> bool:
    """click 8.1 says None where click 8.2+ says Sentinel.UNSET."""
    return value is None or (type(value).__name__ == "Sentinel"
                             and getattr(value, "name", "") == "UNSET")


def default_value(schema: Schema, name: str, mode: str):
    """The built-in default of a key in a mode, as it would be written in the file; None if it
    has none."""
    if name == MODE_KEY:
        return schema.default_mode
    key = schema.keys[name]
    mode = key.mode_for(mode)
    param = key.params[mode]
    value = param.get_default(click.Context(schema.commands[mode], info_name=mode))
    if _is_unset(value):
        return [] if param.multiple else None
    if param.multiple or param.nargs != 1:
        return list(value)
    return value


# --- value kinds and checks ------------------------------------------------------------------

def _kind(param_type: click.ParamType) -> str:
    if isinstance(param_type, click.types.BoolParamType):
        return "bool"
    if isinstance(param_type, click.types.IntParamType):
        return "int"
    if isinstance(param_type, click.types.FloatParamType):
        return "float"
    if isinstance(param_type, (click.types.StringParamType, click.Choice)):
        return "str"
    return "any"


def _element_kinds(param: click.Parameter) -> list[str]:
    if isinstance(param.type, click.Tuple):
        return [_kind(t) for t in param.type.types]
    return [_kind(param.type)] * max(param.nargs, 1)


_KIND_CHECKS = {
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "int": (lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer"),
    "float": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool), "a number"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "any": (lambda v: isinstance(v, (str, int, float, bool)), "a value"),
}


def _kind_problem(kinds: list[str], values: list) -> str | None:
    for kind, value in zip(kinds, values):
        accepts, wanted = _KIND_CHECKS[kind]
        if not accepts(value):
            shown = dump_value(value) if dumpable(value) else repr(value)
            return f"expected {wanted}, got {shown}"
    return None


def _shape_problem(param: click.Parameter, value) -> str | None:
    """Is the TOML value the shape the option takes (scalar, list of N, list)?"""
    if isinstance(value, dict):
        return "expected a value, not a table"
    if param.multiple:
        if not isinstance(value, list):
            return "expected a list, e.g. [\"...\"]"
        if param.nargs != 1:
            return None                    # entries are "A B" strings or lists: click checks
        return next(filter(None, (_kind_problem(_element_kinds(param), [v]) for v in value)),
                    None)
    if param.nargs != 1:
        if not isinstance(value, list) or len(value) != param.nargs:
            return f"expected a list of {param.nargs} values"
        return _kind_problem(_element_kinds(param), value)
    if isinstance(value, list):
        return "expected a single value, not a list"
    return _kind_problem(_element_kinds(param), [value])


def _to_click(name: str, param: click.Parameter, value):
    """A file value as the command line would give it to click."""
    if name == "authip" and param.multiple:
        return [v for v in value if v != NO_ADDRESS]
    if param.multiple and param.nargs != 1:
        return [v.split() if isinstance(v, str) else v for v in value]
    return value


class _Problem(Exception):
    pass


def _process(command: click.Command, param: click.Parameter, value):
    """Convert and check a value exactly as the command line would: type, then callback."""
    ctx = click.Context(command, info_name=command.name)
    try:
        return param.process_value(ctx, value)
    except click.BadParameter as err:
        raise _Problem(err.message) from None
    except click.UsageError as err:
        raise _Problem(err.format_message()) from None
    except (TypeError, ValueError, AttributeError):
        raise _Problem(f"invalid value {value!r}") from None


# --- reading and checking a file ---------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Settings:
    """A checked file: the mode it selects and its key values as written (TOML types)."""
    path: Path
    mode: str
    values: dict               # key name -> value, for the keys present in the file

    def default_map(self, schema: Schema, command_name: str) -> dict:
        """click's default_map for a mode command: its options the file sets.  The authip and
        slaveid tables belong to the file's mode and are left out for the other command."""
        mapping = {}
        for name, value in self.values.items():
            key = schema.keys.get(name)
            param = key.params.get(command_name) if key else None
            if param is None or (name in MODE_TABLES and command_name != self.mode):
                continue
            mapping[param.name] = _to_click(name, param, value)
        return mapping

    def get(self, schema: Schema, name: str):
        """The effective value of a key: the file's, else the built-in default."""
        if name == MODE_KEY:
            return self.mode
        if name in self.values:
            return self.values[name]
        return default_value(schema, name, self.mode)


def read_text(path: Path) -> str:
    """Raises FileNotFoundError, PermissionError (the caller words them)."""
    return Path(path).read_text(encoding="utf-8")


def parse(path: Path, text: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigFileError(path, [f"not valid TOML: {err}"]) from None


def check(schema: Schema, path: Path, data: dict) -> Settings:
    """Every key known, every value accepted by its option; raises ConfigFileError listing all
    the problems found."""
    problems = []
    for name, content in data.items():
        if name in GROUPS:
            if not isinstance(content, dict):
                problems.append(f"{name}: expected a group [{name}], not a value")
        elif isinstance(content, dict):
            match = difflib.get_close_matches(name.lower(), GROUPS, n=1, cutoff=0.6)
            problems.append(f"[{name}]: unknown group (groups: {', '.join(GROUPS)})"
                            + (f"; did you mean [{match[0]}]?" if match else ""))
        elif name == MODE_KEY or name in schema.keys:
            problems.append(f"{name}: outside any group; put it under "
                            f"[{schema.label(name).split('.')[0]}]")
        else:
            problems.append(f"{name}: unknown key{schema.hint(name)}")
    groups = {g: data[g] for g in GROUPS if isinstance(data.get(g), dict)}
    mode = _check_mode(schema, groups.get("serial", {}), problems)
    values = {}
    for group, content in groups.items():
        for name, value in content.items():
            label = f"{group}.{name}"
            if group == "serial" and name == MODE_KEY:
                continue
            key = schema.keys.get(name)
            if key is None:
                problems.append(f"{label}: unknown key{schema.hint(name)}")
            elif key.group != group:
                problems.append(f"{label}: belongs in [{key.group}] ({key.label})")
            else:
                problems += check_value(schema, key, mode, value)
                values[name] = value
    if problems:
        raise ConfigFileError(path, problems)
    return Settings(Path(path), mode, values)


def _check_mode(schema: Schema, serial: dict, problems: list) -> str:
    value = serial.get(MODE_KEY, schema.default_mode)
    if value in schema.modes:
        return value
    label = f"serial.{MODE_KEY}"
    if value in MODES:
        problems.append(f"{label}: {value} mode is not in this mbgw (modes: "
                        f"{', '.join(schema.modes)})")
    elif isinstance(value, str) and value.lower() in PROTOCOL_WORDS:
        problems.append(f"{label}: {value!r} is the framing: write protocol = "
                        f"\"{value.lower()}\" (mode is {' or '.join(MODES)})")
    else:
        problems.append(f"{label}: expected {' or '.join(repr(m) for m in MODES)}, got "
                        f"{value!r}")
    return schema.default_mode


def check_value(schema: Schema, key: Key, mode: str, value) -> list[str]:
    """Problems with one key's value, checked by the option of the file's mode (or of the mode
    that has the key)."""
    mode = key.mode_for(mode)
    command, param = schema.commands[mode], key.params[mode]
    label = key.label
    if key.name == "authip" and param.multiple:
        return _check_authip(command, param, value, label)
    if key.name == "slaveid" and param.multiple:
        return _check_slaveid_table(command, param, value, label)
    shape = _shape_problem(param, value)
    if shape:
        return [f"{label}: {shape}"]
    if param.multiple:
        problems = []
        for index, element in enumerate(value, 1):
            try:
                _process(command, param, _to_click(key.name, param, [element]))
            except _Problem as problem:
                problems.append(f"{label}[{index}]: {problem}")
        if problems:
            return problems
    try:
        _process(command, param, _to_click(key.name, param, value))
    except _Problem as problem:
        return [f"{label}: {problem}"]
    return []


def _check_authip(command, param, value, label) -> list[str]:
    if not isinstance(value, list):
        return [f"{label}: expected a list of addresses, e.g. [\"192.168.1.5\"]"]
    if len(value) > AUTHIP_ENTRIES:
        return [f"{label}: {len(value)} entries, the table holds {AUTHIP_ENTRIES}"]
    problems = []
    for index, entry in enumerate(value, 1):
        if not isinstance(entry, str):
            problems.append(f"{label}[{index}]: expected an address string, got {entry!r}")
        elif entry != NO_ADDRESS:
            try:
                _process(command, param, [entry])
            except _Problem as problem:
                problems.append(f"{label}[{index}]: {problem}")
    return problems


def _check_slaveid_table(command, param, value, label) -> list[str]:
    """Master mode's table: each entry a range "FS LS FR M IP", no two ranges overlapping
    (in a file, a range whose FS lies in another would silently replace it)."""
    if not isinstance(value, list):
        return [f"{label}: in master mode, a list of ranges \"FS LS FR M IP\""]
    problems, ranges = [], []
    for index, entry in enumerate(value, 1):
        try:
            if not isinstance(entry, str):
                raise ConfigError(f"expected a string \"FS LS FR M IP\", got {entry!r}")
            entry_range = SlaveRange.parse(entry)
            if entry_range is None:
                raise ConfigError("FS 0 clears the table: leave the list empty instead")
        except ConfigError as problem:
            problems.append(f"{label}[{index}]: {problem}")
            continue
        for other_index, other in ranges:
            if entry_range.first <= other.last and other.first <= entry_range.last:
                problems.append(f"{label}[{index}]: addresses {entry_range.first}.."
                                f"{entry_range.last} overlap {label}[{other_index}] "
                                f"({other.first}..{other.last})")
        ranges.append((index, entry_range))
    if not problems:
        try:
            _process(command, param, value)
        except _Problem as problem:
            problems.append(f"{label}: {problem}")
    return problems


def load(schema: Schema, path: Path) -> Settings:
    """Read and check a file that must exist; raises ConfigFileError, or PermissionError (for
    the caller to suggest sudo)."""
    try:
        text = read_text(path)
    except FileNotFoundError:
        raise ConfigFileError(path, ["no such file (create it with: mbgw config default"
                                     + ("" if Path(path) == DEFAULT_PATH else f" --config {path}")
                                     + ")"]) from None
    except PermissionError:
        raise
    except OSError as err:
        raise ConfigFileError(path, [f"cannot read it: {err.strerror or err}"]) from None
    return check(schema, path, parse(path, text))


def resolve(schema: Schema, settings: Settings, args=(), mode: str | None = None,
            given=()) -> dict:
    """The parameters of a mode command (the file's mode, or `mode`) as its function receives
    them, from the file and `args` (command-line options, which win).  Also checks what only
    the whole command can: options it requires (device), callbacks.  `given`: names of
    parameters the caller has from elsewhere (a running daemon's command line), which the
    file need not have even when required.  Raises ConfigFileError."""
    mode = mode or settings.mode
    command = schema.commands[mode]
    if any(p.required and p.name in given for p in command.params):
        command = copy.copy(command)
        command.params = [_optional(p) if p.name in given else p for p in command.params]
    try:
        ctx = command.make_context(mode, list(args),
                                   default_map=settings.default_map(schema, mode))
    except click.ClickException as err:
        raise ConfigFileError(settings.path, [click_problem(schema, settings, err)]) from None
    return {name: None if _is_unset(v) else v for name, v in ctx.params.items()}


def _optional(param: click.Parameter) -> click.Parameter:
    param = copy.copy(param)
    param.required = False
    return param


def click_problem(schema: Schema, settings: Settings, err: click.ClickException) -> str:
    param = getattr(err, "param", None)
    key = schema.key_of_param(param) if param is not None else None
    if key is None:
        return err.format_message()
    if isinstance(err, click.MissingParameter):
        return (f"{key.label}: missing; {settings.mode} mode needs it (e.g. mbgw config set "
                f"{key.group} {key.name} {FACTORY_DEVICE if key.name == 'device' else '...'})")
    return f"{key.label}: {err.message}"


def load_options(path=DEFAULT_PATH, args=(), root: click.Group | None = None,
                 mode: str | None = None, given=()) -> dict:
    """What `mbgw run --config PATH ARGS...` would start, without starting it: {"mode": "slave"
    or "master", then every parameter of that mode's command exactly as click passes it to the
    command's function (converted, checked, defaults filled in)}.  `args` are command-line
    options that win over the file; `mode` takes another mode than the file's (as `mbgw slave
    --config PATH` does).  Raises ConfigFileError (a ConfigError) naming the file, the key and
    the reason.  The file is only read, so a daemon can call it on SIGHUP and keep running on
    an error (see mbgw.cli_config.reloader), passing as `given` the parameters its command
    line set (see resolve)."""
    if root is None:
        from mbgw.cli import main as root
    schema = Schema(root)
    try:
        settings = load(schema, Path(path))
    except PermissionError as err:
        raise ConfigFileError(path, [f"cannot read it: {err.strerror}"]) from None
    mode = mode or settings.mode
    return {"mode": mode, **resolve(schema, settings, args, mode, given)}


# --- changes in the guide's syntax -------------------------------------------------------------

def changes_for_set(schema: Schema, settings: Settings, group: str, name: str,
                    words: list[str]) -> dict:
    """`set GROUP PARAM VALUE...` as {key: new value} (a value of _REMOVE takes the key out).
    Raises ConfigError naming the key and the reason; the new file is checked afterwards."""
    name = name.lower()
    if group == "serial" and name == MODE_KEY:
        return _set_mode(schema, settings, words)
    key = schema.keys.get(name)
    if key is None:
        raise ConfigError(f"{group}.{name}: unknown key{schema.hint(name)}")
    if key.group != group:
        raise ConfigError(f"{group}.{name}: belongs in [{key.group}]: mbgw config set "
                          f"{key.group} {name} ...")
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
        converted = _process(command, param, value)
        text = converted if isinstance(converted, str) else str(converted)
        if text != value and _process(command, param, text) == converted:
            return text
    except _Problem:
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
    changes = {MODE_KEY: word}
    if word != settings.mode:
        changes.update({table: _REMOVE for table in MODE_TABLES if table in settings.values})
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
    return [f"{r.first} {r.last} {r.remote_first} {int(r.variable_ip)} {r.ip}" for r in ranges]


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
    kinds = _element_kinds(param)
    if param.multiple:
        return [_word_value(kinds[0], w, key.label) if param.nargs == 1 else w for w in words]
    if param.nargs != 1:
        if len(words) != param.nargs:
            raise ConfigError(f"{key.label}: expected {param.nargs} values, got {len(words)}")
        return [_word_value(k, w, key.label) for k, w in zip(kinds, words)]
    if kinds[0] in ("bool", "int", "float"):
        if len(words) != 1:
            raise ConfigError(f"{key.label}: expected one value, got {' '.join(words)!r}")
        return _word_value(kinds[0], words[0], key.label)
    return JOIN_WORDS.get(key.name, " ").join(words)


def apply_changes(data: dict, schema: Schema, changes: dict) -> dict:
    """The parsed file with the changes made (a new dict)."""
    new = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for name, value in changes.items():
        group = schema.label(name).split(".")[0]
        content = new.setdefault(group, {})
        if value is _REMOVE:
            content.pop(name, None)
        else:
            content[name] = value
    return new


# --- the text: the factory file, edits that keep comments -------------------------------------

def default_line(schema: Schema, name: str, mode: str) -> str:
    """The commented-out line showing a key's built-in default."""
    value = default_value(schema, name, mode)
    return f"# {name} =" if value is None else f"# {name} = {dump_value(value)}"


_NOTES = {
    MODE_KEY: ["slave: Modbus slaves on the serial line, reached by Modbus TCP clients; master: "
               "a Modbus master on the line, reaching Modbus TCP servers. Also 'mbgw config "
               "set serial mode rtu|ascii' sets the protocol. Changing the mode clears the "
               "net.authip and net.slaveid tables."],
    "authip": [f"Set with: mbgw config set net authip N IP (entry N 1..{AUTHIP_ENTRIES}; "
               f"{NO_ADDRESS} clears it). The entries are the list items in order."],
    "slaveid": ["Set with: mbgw config set net slaveid SA (slave mode), or ... slaveid FS LS "
                "FR M IP once per range (master mode; FS 0 clears the table)."],
}


def _describe(schema: Schema, name: str) -> list[str]:
    """The help of a key's option(s), as comment lines; "(slave mode) ..." where the modes'
    options differ or only one mode has it."""
    lines = []
    if name != MODE_KEY:
        key = schema.keys[name]
        texts = {}
        for mode, param in key.params.items():
            text = param.help or ""
            if isinstance(param.type, click.Choice):
                text += f" One of: {', '.join(map(str, param.type.choices))}."
            texts[mode] = text.strip()
        if len(key.params) == len(schema.modes) and len(set(texts.values())) == 1:
            lines.append(texts[schema.modes[0]])
        else:
            lines += [f"({mode} mode) {text}" for mode, text in texts.items()]
    if name != "slaveid" or "master" in schema.modes:
        lines += _NOTES.get(name, [])
    return [c for text in lines if text for c in textwrap.wrap(
        text, 92, initial_indent="# ", subsequent_indent="# ")]


def factory_text(schema: Schema) -> str:
    """The factory-default file: every key with its help, commented out at its built-in
    default, except mode and device (the device has no built-in default)."""
    mode = schema.default_mode
    out = ["# mbgw configuration: one gateway, one serial line. The keys are the options of",
           "# 'mbgw slave --help' and 'mbgw master --help' (the ACKSYS command names); the",
           "# command line wins over this file, and a key left out or commented out takes the",
           "# built-in default shown.",
           "#   mbgw config show                  the effective settings",
           "#   mbgw config set serial stout 700  change one (checked, written atomically)",
           "#   mbgw check-config                 check this file",
           "#   systemctl reload mbgw             apply it to the running service"]
    for group in GROUPS:
        names = schema.group_keys(group)
        if not names:
            continue
        out += ["", f"[{group}]"]
        for name in names:
            out += ["", *_describe(schema, name)]
            if name == MODE_KEY:
                out.append(f"{MODE_KEY} = {dump_value(mode)}")
            elif name == "device":
                out.append(f"device = {dump_value(FACTORY_DEVICE)}")
            else:
                out.append(default_line(schema, name, mode))
    return "\n".join(out) + "\n"


def edit(text: str, schema: Schema, mode: str, changes: dict) -> str:
    """Apply {key: value or _REMOVE} to the file text (see set_line)."""
    for name, value in changes.items():
        group = schema.label(name).split(".")[0]
        if value is _REMOVE:
            text = set_line(text, group, name, None,
                            None if name == MODE_KEY else default_line(schema, name, mode))
        else:
            text = set_line(text, group, name, f"{name} = {dump_value(value)}")
    return text


def remove(name: str) -> dict:
    """The change that takes a key out of the file (back to its built-in default)."""
    return {name: _REMOVE}
