"""The configuration file, /etc/mbgw/mbgw.toml (`mbgw@NAME` reads /etc/mbgw/NAME.toml):
reading and checking it, and the options it gives a mode command.

It holds every option of both modes under its ACKSYS name, grouped like the ACKSYS guide:
[serial] (mode, device, baudrate, format, stout, ...), [net] (slaveid, authip, mdbport, tcpto,
...) and [general] (what the guide has no command for).  The keys are the long options of the
mode commands (mbgw.config.schema).  A value is checked by its option's own click type and
callback (mbgw.config.values), and reaches the command through click's default_map: command
line > file > built-in default.  Changes go through `mbgw config set` (the guide's `set`
syntax, mbgw.config.edit), which edits the text in place so that comments survive
(mbgw.config.text), and replaces the file atomically."""
import copy
import dataclasses
import difflib
import re
import tomllib
from pathlib import Path

import click

from mbgw.config import firewall as fw
from mbgw.config import line_file
from mbgw.config.lines import LINE_MODES
from mbgw.config.model import NO_DEVICE
from mbgw.config.monitor import MONITOR_TABLE, parse_monitors
from mbgw.config.scenario import parse_scenarios
from mbgw.config.schema import (
    DEFAULT_PATH,
    FACTORY_DEVICE,
    GROUPS,
    MODE_KEY,
    MODE_TABLES,
    MODES,
    NOT_SUPPORTED,
    PROTOCOL_WORDS,
    Schema,
    default_value,
    is_unset,
)
from mbgw.config.tables import array_of_tables
from mbgw.config.values import check_across, check_value, to_click
from mbgw.errors import ConfigFileError

SCENARIO_KEY = "scenario"       # [[scenario]]: an array of tables, beside the groups
SCENARIOS_PARAM = "scenarios"   # the mode commands' hidden parameter the file fills
DEVICE_PARAM = "device"         # serial.device's parameter


@dataclasses.dataclass(frozen=True)
class Settings:
    """A checked file: the mode it selects and its key values as written (TOML types)."""
    path: Path
    mode: str
    values: dict               # key name -> value, for the keys present in the file
    firewall: fw.FirewallConfig = fw.FirewallConfig()   # [firewall], [[rule]]
    scenarios: tuple = ()      # the [[scenario]] tables, checked (ScenarioConfig)
    lines: tuple = ()          # the [[line]] tables, checked (line_file.LineTable)
    routes: tuple = ()         # the [[route]] tables (RouteConfig)
    monitors: tuple = ()       # the [[monitor]] maps (MonitorMap)
    devices: tuple = ()        # the [[device]] tables (DeviceConfig)

    @property
    def without_serial(self) -> bool:
        """A slave-mode file whose [[line]] tables define the lines, [serial] (or its device)
        left out: line serial does not run, [serial]'s other keys are the lines' defaults."""
        return self.mode == "slave" and DEVICE_PARAM not in self.values and bool(self.lines)

    def default_map(self, schema: Schema, command_name: str) -> dict:
        """click's default_map for a mode command: its options the file sets.  The authip and
        slaveid tables belong to the file's mode and are left out for the other command."""
        mapping = {}
        for name, value in self.values.items():
            key = schema.keys.get(name)
            param = key.params.get(command_name) if key else None
            if param is None or (name in MODE_TABLES and command_name != self.mode):
                continue
            mapping[param.name] = to_click(name, param, value)
        if any(p.name == fw.PARAM for p in schema.commands[command_name].params):
            mapping[fw.PARAM] = self.firewall
        if self.scenarios:
            mapping[SCENARIOS_PARAM] = self.scenarios
        if self.lines:
            mapping[line_file.LINES_PARAM] = self.lines
        if self.routes:
            mapping[line_file.ROUTES_PARAM] = self.routes
        if self.monitors:
            mapping[line_file.MONITORS_PARAM] = self.monitors
        if self.devices:
            mapping[line_file.DEVICES_PARAM] = self.devices
        if self.without_serial and command_name == self.mode:
            mapping[DEVICE_PARAM] = NO_DEVICE       # line serial does not run
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


MAX_NESTING = 8         # arrays and tables in one another: the deepest key needs 3


def parse(path: Path, text: str) -> dict:
    try:
        data = tomllib.loads(text)
        if nesting(data) > MAX_NESTING:
            raise RecursionError
    except tomllib.TOMLDecodeError as err:
        raise ConfigFileError(path, [f"not valid TOML: {err}"]) from None
    except RecursionError:
        raise ConfigFileError(path, [f"arrays or tables nested more than {MAX_NESTING} deep: "
                                     f"no key of mbgw's is"]) from None
    return data


def nesting(value) -> int:
    """How deep arrays and tables are in one another in value (a scalar: 0)."""
    depth, level = 0, [value]
    while True:
        containers = [v for v in level if isinstance(v, (list, dict))]
        if not containers:
            return depth
        depth += 1
        level = [v for c in containers for v in (c.values() if isinstance(c, dict) else c)]


def _top_level_problems(schema: Schema, data: dict) -> list[str]:
    """What is wrong at the file's top level: unknown groups, keys outside a group."""
    problems = []
    for name, content in data.items():
        if name in (fw.GROUP, fw.RULE_TABLE, SCENARIO_KEY, line_file.LINE_TABLE,
                    line_file.ROUTE_TABLE, MONITOR_TABLE, line_file.DEVICE_TABLE):
            continue                    # fw.from_file's, parse_scenarios', line_file's
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
    return problems


def check(schema: Schema, path: Path, data: dict) -> Settings:
    """Every key known, every value accepted by its option; raises ConfigFileError listing all
    the problems found."""
    problems = _top_level_problems(schema, data)
    groups = {g: data[g] for g in GROUPS if isinstance(data.get(g), dict)}
    mode = _check_mode(schema, groups.get("serial", {}), problems)
    values = {}
    for group, content in groups.items():
        for name, value in content.items():
            label = f"{group}.{name}"
            if group == "serial" and name == MODE_KEY:
                continue
            key = schema.find(group, name)
            elsewhere = schema.keys.get(name)
            if key is not None:
                problems += check_value(schema, key, mode, value)
                values[key.name] = value
            elif elsewhere is not None and elsewhere.file_name == name:
                problems.append(f"{label}: belongs in [{elsewhere.group}] ({elsewhere.label})")
            elif (group, name) in NOT_SUPPORTED:
                problems.append(f"{label}: {NOT_SUPPORTED[group, name]}")
            else:
                problems.append(f"{label}: unknown key{schema.hint(name)}")
    rules, firewall_problems = fw.from_file(data)
    problems += firewall_problems
    if not problems:
        problems = check_across(schema, mode, values)
    scenarios, scenario_problems = parse_scenarios(data.get(SCENARIO_KEY, []), mode)
    problems += scenario_problems
    lines, line_problems = line_file.parse_lines(
        schema, array_of_tables(data, line_file.LINE_TABLE, problems), mode)
    routes, route_problems = line_file.parse_routes(
        array_of_tables(data, line_file.ROUTE_TABLE, problems))
    monitors, monitor_problems = parse_monitors(
        array_of_tables(data, MONITOR_TABLE, problems))
    devices, device_problems = line_file.parse_devices(
        array_of_tables(data, line_file.DEVICE_TABLE, problems))
    problems += line_problems + route_problems + monitor_problems + device_problems
    if monitors and mode not in LINE_MODES:
        problems.append(f"monitor: [[monitor]] maps are for slave and master modes; {mode} "
                        f"mode bridges [serial] only")
    if devices and mode not in LINE_MODES:
        problems.append(f"device: [[device]] tables are for slave and master modes; {mode} "
                        f"mode bridges [serial] only")
    if routes and mode not in LINE_MODES:
        problems.append(f"route: [[route]] tables are for slave and master modes; {mode} mode "
                        f"bridges [serial] only")
    problems += line_file.table_units_overlap(values, routes)
    if problems:
        raise ConfigFileError(path, problems)
    return Settings(Path(path), mode, values, rules, scenarios, lines, routes, monitors,
                    devices)


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



def load(schema: Schema, path: Path) -> Settings:
    """Read and check a file that must exist; raises ConfigFileError, or PermissionError (for
    the caller to suggest sudo)."""
    try:
        text = read_text(path)
    except FileNotFoundError:
        raise ConfigFileError(path, [f"no such file (create it with: mbgw config default"
                                     f"{file_words(path)})"]) from None
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
    # the root's help options: click keeps the first context's on the command (-h, later)
    helps = (schema.root.context_settings or {}).get("help_option_names", ["--help"])
    try:
        ctx = command.make_context(mode, list(args), help_option_names=helps,
                                   default_map=settings.default_map(schema, mode))
    except click.ClickException as err:
        raise ConfigFileError(settings.path, [click_problem(schema, settings, err)]) from None
    return {name: None if is_unset(v) else v for name, v in ctx.params.items()}


def _optional(param: click.Parameter) -> click.Parameter:
    param = copy.copy(param)
    param.required = False
    return param


def file_words(path) -> str:
    """' --config PATH' for a hint's command, or '' for the default file."""
    return "" if Path(path) == DEFAULT_PATH else f" --config {path}"


def with_file(problem: str, path) -> str:
    """A problem whose hint names a `mbgw config password` command, for the file in use."""
    return _PASSWORD_HINT.sub(lambda m: m.group(0) + file_words(path), problem)


_PASSWORD_HINT = re.compile(r"mbgw config password( (admin|user))?(?=\)|$)")


def click_problem(schema: Schema, settings: Settings, err: click.ClickException) -> str:
    param = getattr(err, "param", None)
    key = schema.key_of_param(param) if param is not None else None
    if key is None:
        return err.format_message()
    if isinstance(err, click.MissingParameter):
        return (f"{key.label}: missing; {settings.mode} mode needs it (e.g. mbgw config set "
                f"{key.group} {key.name} {FACTORY_DEVICE if key.name == 'device' else '...'}"
                f"{file_words(settings.path)})")
    return f"{key.label}: {err.message}"


def load_options(root: click.Group, path=DEFAULT_PATH, args=(), mode: str | None = None,
                 given=()) -> dict:
    """What `mbgw run --config PATH ARGS...` (root: the mbgw command group) would start,
    without starting it: {"mode": "slave"
    or "master", then every parameter of that mode's command exactly as click passes it to the
    command's function (converted, checked, defaults filled in)}.  `args` are command-line
    options that win over the file; `mode` takes another mode than the file's (as `mbgw slave
    --config PATH` does).  Raises ConfigFileError (a ConfigError) naming the file, the key and
    the reason.  The file is only read, so a daemon can call it on SIGHUP and keep running on
    an error (see mbgw.cli.config_option.reloader), passing as `given` the parameters its command
    line set (see resolve)."""
    schema = Schema(root)
    try:
        settings = load(schema, Path(path))
    except PermissionError as err:
        raise ConfigFileError(path, [f"cannot read it: {err.strerror}"]) from None
    mode = mode or settings.mode
    return {"mode": mode, **resolve(schema, settings, args, mode, given)}

