"""The configuration-file commands: `mbgw run`, `mbgw check-config`, `mbgw config show|set|
unset|default`, and the --config option of the mode commands.  register(main) adds them."""
import shlex
import tomllib
from pathlib import Path

import click

from mbgw.cli import checks
from mbgw.cli.options import EX_CONFIG, META_FILE, Failure, ModeCommand
from mbgw.config import line_file, scenario_text
from mbgw.config import scenario as scenario_config
from mbgw.config import schema as config_schema  # DEFAULT_PATH, CONFIG_DIR read at each call
from mbgw.config.edit import REMOVE, apply_changes, changes_for_set, show_lines
from mbgw.config.file import (
    SCENARIO_KEY,
    SCENARIOS_PARAM,
    Settings,
    check,
    click_problem,
    load,
    load_options,
    parse,
    read_text,
)
from mbgw.config.lines import LINE_MODES, TCP_FACE, implicit_routes
from mbgw.config.number_list import number_list_text
from mbgw.config.schema import GROUPS, MODE_KEY, MODES, Schema
from mbgw.config.text import default_line, edit, factory_text
from mbgw.config.toml_text import dump_value, set_line, write_atomic
from mbgw.errors import ConfigError, ConfigFileError

SHOW_WIDTH = 16                    # the key column of `mbgw config show`
META_MODE_FROM_FILE = "mbgw.mode_from_file"   # ctx.meta: `mbgw run` took the mode from it


def register(root: click.Group) -> None:
    """Add the commands to `root`, and a --config FILE option to its mode commands."""
    ModeCommand.file_values = staticmethod(_file_values)
    for mode in MODES:
        command = root.commands.get(mode)
        if command is not None and not any(p.name == "config" for p in command.params):
            command.params.append(_mode_config_option())
            command.params.append(_scenarios_option())
            if mode in LINE_MODES and isinstance(command, ModeCommand):   # make_config's
                command.params += [_given_option(line_file.LINES_PARAM),
                                   _given_option(line_file.ROUTES_PARAM)]
    for command in (run, check_config, config):
        root.add_command(command)


def schema_of(ctx: click.Context) -> Schema:
    root = ctx.find_root().command
    if not isinstance(root, click.Group) or not any(m in root.commands for m in MODES):
        root = click.Group(commands=[ctx.command])
    return Schema(root)


def _command_line(ctx: click.Context, *words) -> str:
    return shlex.join([*ctx.command_path.split(), *map(str, words)])


def _permission_failure(ctx, path, doing: str, words, exit_code: int = 1) -> Failure:
    return Failure(f"cannot {doing} {path}: permission denied; run it as root: "
                   f"sudo {_command_line(ctx, *words)}", exit_code)


def _load(ctx: click.Context, schema: Schema, path: Path, words=(),
          exit_code: int = 1) -> Settings:
    try:
        return load(schema, path)
    except PermissionError:
        raise _permission_failure(ctx, path, "read", words, exit_code) from None
    except ConfigFileError as err:
        raise Failure(str(err), exit_code) from None


# --- the --config option of `mbgw slave` / `mbgw master` -----------------------------------------

def _mode_config_option() -> click.Option:
    return click.Option(
        ["--config"], metavar="FILE", type=click.Path(dir_okay=False), envvar="MBGW_CONFIG",
        is_eager=True, expose_value=False, callback=_apply_file,
        help=f"Take the options not given here from FILE [default: "
             f"{config_schema.DEFAULT_PATH}, when it exists; also $MBGW_CONFIG].")


class _GivenValue(click.ParamType):
    """A value the configuration file hands over already checked (the scenarios)."""
    name = "given"

    def convert(self, value, param, ctx):
        return value


def _scenarios_option() -> click.Option:
    """The file's [[scenario]] tables (ScenarioConfig), through click's default_map like the
    other keys' values: hidden, no command-line form."""
    return click.Option(["--scenarios", SCENARIOS_PARAM], type=_GivenValue(), default=(),
                        hidden=True)


def _given_option(name: str) -> click.Option:
    """The file's [[line]] or [[route]] tables, handed over like the scenarios."""
    return click.Option([f"--{name}", name], type=_GivenValue(), default=(), hidden=True)


def _apply_file(ctx: click.Context, param: click.Parameter, value) -> None:
    """Eager: runs before the other options take their values, and gives them the file's
    values as defaults (click's default_map), so the command line wins over the file."""
    given = ctx.get_parameter_source(param.name) == click.core.ParameterSource.COMMANDLINE
    if ctx.default_map is not None and not given:   # `mbgw run`, load_options gave the file
        return
    if value is None:
        if not config_schema.DEFAULT_PATH.exists():
            return
        value = config_schema.DEFAULT_PATH
    schema = schema_of(ctx)
    settings = _load(ctx, schema, Path(value), exit_code=EX_CONFIG)
    if (settings.lines or settings.routes) and not any(
            p.name == line_file.LINES_PARAM for p in ctx.command.params):
        raise Failure(f"{value}: line: [[line]] and [[route]] tables are for slave and master "
                      f"modes; {ctx.command.name} mode bridges [serial] only", EX_CONFIG)
    ctx.default_map = {**settings.default_map(schema, ctx.command.name or ""),
                       **(ctx.default_map or {})}
    ctx.meta[META_FILE] = Path(value)


def _file_values(ctx: click.Context) -> tuple[Path, dict] | None:
    """For -h: the file a mode command takes its values from (--config, else $MBGW_CONFIG,
    else the default file when it exists) and its values; None when there is none, or when
    it cannot be read (the command itself says why)."""
    path = ctx.meta.get(META_FILE)
    if path is not None and ctx.default_map:
        return path, dict(ctx.default_map)
    import os
    path = Path(os.environ.get("MBGW_CONFIG") or config_schema.DEFAULT_PATH)
    if not path.exists():
        return None
    try:
        settings = load(schema_of(ctx), path)
    except (OSError, ConfigFileError):
        return None
    return path, settings.default_map(schema_of(ctx), ctx.command.name or "")


def config_file(ctx: click.Context | None = None) -> Path | None:
    """The configuration file the running mode command took values from, or None."""
    ctx = ctx or click.get_current_context()
    return ctx.meta.get(META_FILE)


def reloader(ctx: click.Context | None = None):
    """For the mode command running now (its context, by default the current one): a function
    that reads its configuration file again, for SIGHUP, and returns {"mode": ..., then the
    command's parameters as its function received them}: the file's values, with the options
    given on the command line (or by environment) kept as they were.  It raises ConfigError
    (the message names the file, the key and the reason) when the file is wrong, or when
    `mbgw run` took the mode from the file and it has changed (a restart is needed).  None
    when the command took nothing from a file."""
    ctx = ctx or click.get_current_context()
    path = ctx.meta.get(META_FILE)
    if path is None:
        return None
    mode = ctx.command.name
    root = schema_of(ctx).root
    kept = {name: ctx.params[name] for name in ctx.params
            if ctx.get_parameter_source(name) in (click.core.ParameterSource.COMMANDLINE,
                                                  click.core.ParameterSource.ENVIRONMENT)}
    from_file = ctx.meta.get(META_MODE_FROM_FILE, False)

    def reload() -> dict:
        options = load_options(root, path, mode=None if from_file else mode,
                                  given=kept)
        if options["mode"] != mode:
            raise ConfigError(f"{path}: serial.mode is {options['mode']} now: changing the "
                              f"mode needs a restart (systemctl restart mbgw)")
        return {**options, **kept}
    return reload


# --- the file options of the other commands -------------------------------------------------

def _file_options(function):
    function = click.option(
        "-i", "--instance", metavar="NAME",
        help=f"The file of the service instance mbgw@NAME: "
             f"{config_schema.CONFIG_DIR}/NAME.toml.")(function)
    return click.option(
        "--config", "config_path", metavar="FILE", envvar="MBGW_CONFIG",
        type=click.Path(dir_okay=False, path_type=Path), default=config_schema.DEFAULT_PATH,
        show_default=True, help="The configuration file (also $MBGW_CONFIG).")(function)


def _path(ctx: click.Context, config_path: Path, instance: str | None) -> Path:
    if instance is None:
        return Path(config_path)
    if ctx.get_parameter_source("config_path") == click.core.ParameterSource.COMMANDLINE:
        raise click.UsageError("give --config or --instance, not both")
    return config_schema.CONFIG_DIR / f"{check_instance(instance)}.toml"


def check_instance(instance: str) -> str:
    """NAME of the service instance mbgw@NAME; a usage error when it cannot be one."""
    if not instance or "/" in instance or instance.startswith("."):
        raise click.BadParameter(f"{instance!r}: a name such as ttyUSB1",
                                 param_hint="'--instance'")
    return instance


def _file_words(ctx: click.Context, path: Path) -> list[str]:
    """The file options to repeat in a suggested command."""
    return [] if path == config_schema.DEFAULT_PATH else ["--config", str(path)]


def _say_how_to_apply(path: Path) -> None:
    """Print the command that makes the running service take the file, when it is a
    service's file."""
    if path == config_schema.DEFAULT_PATH:
        click.echo("apply it with: systemctl reload mbgw")
    elif path.parent == config_schema.CONFIG_DIR and path.suffix == ".toml":
        click.echo(f"apply it with: systemctl reload mbgw@{path.stem}")


def _write(ctx, path: Path, text: str, words, what: str) -> None:
    """Write the file; what: the change, for the journal's audit event."""
    try:
        write_atomic(path, text)
    except PermissionError:
        raise _permission_failure(ctx, path, "write", words) from None
    except OSError as err:
        raise Failure(f"cannot write {path}: {err.strerror or err}") from None
    _audit(ctx, path, what)


def _audit(ctx, path: Path, what: str) -> None:
    """A change of the file as an audit event in the journal (journald adds the sender's
    _UID, _PID and _COMM itself); nothing on a machine without one."""
    import os

    from mbgw.audit import Kind
    from mbgw.ops.log import journal_event
    user = f"uid {os.getuid()}"
    if os.environ.get("SUDO_UID"):
        user += f" (sudo from uid {os.environ['SUDO_UID']})"
    journal_event("mbgw.config", Kind.CONFIG_CHANGED,
                  f"configuration changed by {ctx.command_path} ({user}): {path}: {what}",
                  source="cli", user=user, keys=what, file=str(path))


# --- mbgw run, mbgw check-config ----------------------------------------------------------------

@click.command("run", context_settings={"ignore_unknown_options": True,
                                        "allow_interspersed_args": False})
@_file_options
@click.argument("args", nargs=-1, type=click.UNPROCESSED, metavar="[MODE OPTIONS]...")
@click.pass_context
def run(ctx: click.Context, config_path: Path, instance: str | None, args) -> None:
    """Start the mode the configuration file selects (serial.mode): what the mbgw service
    runs.  Options after the file options are the mode command's and win over the file,
    e.g. `mbgw run --log-level debug`.  Exit status 78 when the file is wrong."""
    path = _path(ctx, config_path, instance)
    schema = schema_of(ctx)
    settings = _load(ctx, schema, path, exit_code=EX_CONFIG)
    command = schema.commands[settings.mode]
    ctx.meta[META_FILE] = path                  # shared with the mode command's context
    ctx.meta[META_MODE_FROM_FILE] = True
    try:
        sub = command.make_context(settings.mode, list(args), parent=ctx,
                                   default_map=settings.default_map(schema, settings.mode))
    except click.MissingParameter as err:
        raise Failure(f"{path}: {click_problem(schema, settings, err)}", EX_CONFIG) \
            from None
    with sub:
        command.invoke(sub)


@click.command("check-config")
@_file_options
@click.argument("file", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.pass_context
def check_config(ctx: click.Context, config_path: Path, instance: str | None,
                 file: Path | None) -> None:
    """Check a configuration file without starting anything: every key known, every value
    accepted as on the command line, what its mode requires present, the keys that go
    together, the files it names (certificates and their keys, the table's file) and the
    addresses it listens on: whatever `mbgw run` would refuse.  Exit status 78 when the file
    is wrong.  FILE (or --config FILE, or -i NAME) defaults to $MBGW_CONFIG, else
    /etc/mbgw/mbgw.toml."""
    if file is not None and (instance is not None or ctx.get_parameter_source("config_path")
                             == click.core.ParameterSource.COMMANDLINE):
        raise click.UsageError("give FILE, --config FILE or -i NAME: one of them")
    path = file or _path(ctx, config_path, instance)
    schema = schema_of(ctx)
    settings = _load(ctx, schema, path, [path], exit_code=EX_CONFIG)
    try:
        checks.check_file(schema, settings)
    except ConfigFileError as err:
        raise Failure(str(err), EX_CONFIG) from None
    for warning in scenario_config.overlaps(settings.scenarios):
        click.echo(f"mbgw: warning: {path}: {warning}", err=True)
    click.echo(f"{path}: ok ({settings.mode} mode)")


# --- mbgw config ... -----------------------------------------------------------------------------

@click.group("config")
def config() -> None:
    """Show and change the configuration file with the ACKSYS commands: `mbgw config set
    serial stout 700` is the guide's `set serial stout 700`.  Each change is checked like the
    command line and written atomically; the running service takes it on `systemctl reload
    mbgw`."""


@config.command("show")
@_file_options
@click.option("--security", is_flag=True,
              help="The security settings in force instead: listeners (address, port, plain "
                   "or TLS, limits), TLS versions and suites, CRL, authip, the firewall, the "
                   "web console (which passwords are set, never their hashes), the control "
                   "socket, and who may read the file.")
@click.option("--json", "as_json", is_flag=True, help="With --security: as a JSON document.")
@click.argument("group", required=False, type=click.Choice(
    [*GROUPS, SCENARIO_KEY, line_file.LINE_TABLE, line_file.ROUTE_TABLE]))
@click.argument("param", required=False)
@click.pass_context
def show(ctx, config_path: Path, instance: str | None, security: bool, as_json: bool,
         group: str | None, param: str | None) -> None:
    """Show the settings in effect (the file's, else the built-in defaults): all, one GROUP
    (serial, net, general, table), or one PARAM, like the guide's `show serial stout`;
    `show scenario [NAME]`: the scenarios; `show line [NAME]`: the [[line]] tables; `show
    route`: the [[route]] tables, then the implicit routes (today's routing of a face without
    a route) as comments; `show --security [--json]`: the security settings in force."""
    if as_json and not security:
        raise click.UsageError("--json goes with --security")
    if security and group is not None:
        raise click.UsageError("--security shows them all: give no GROUP")
    path = _path(ctx, config_path, instance)
    schema = schema_of(ctx)
    if path.exists():
        settings = _load(ctx, schema, path, [*filter(None, (group, param)),
                                             *(["--security"] if security else []),
                                             *_file_words(ctx, path)])
    else:
        click.echo(f"mbgw: {path} does not exist: built-in defaults", err=True)
        settings = Settings(path, schema.default_mode, {})
    if security:
        _show_security(schema, settings, as_json)
    elif not _show_tables(schema, settings, group, param):
        _show_groups(schema, settings, group, param)


def _show_tables(schema: Schema, settings: Settings, group: str | None,
                 param: str | None) -> bool:
    """`show scenario|line|route [NAME]`: True when group was one of those."""
    if group == SCENARIO_KEY:
        _show_scenarios(settings, param)
    elif group == line_file.LINE_TABLE:
        _show_lines(settings, param, separate=False)
    elif group == line_file.ROUTE_TABLE:
        _show_routes(schema, settings, separate=False)
    else:
        return False
    return True


def _show_groups(schema: Schema, settings: Settings, group: str | None,
                 param: str | None) -> None:
    if param is not None:
        name = param.lower()
        key = schema.find(group, name) if group else None
        if key is None and not (group == "serial" and name == MODE_KEY):
            raise click.BadParameter(f"{group}.{param}: unknown{schema.hint(name)}",
                                     param_hint="PARAM")
        name = key.name if key is not None else name
        for line in show_lines(schema, settings, name):
            click.echo(line)
        return
    for shown in [group] if group else GROUPS:
        names = schema.group_keys(shown)
        if not names:
            continue
        click.echo(f"[{shown}]")
        for name in names:
            for line in show_lines(schema, settings, name):
                click.echo(f"{schema.file_name(name):<{SHOW_WIDTH}} {line}")
    if group is None and settings.scenarios:
        _show_scenarios(settings, None)
    if group is None and settings.lines:
        _show_lines(settings, None)
    if group is None and (settings.routes or settings.lines):
        _show_routes(schema, settings)


def _show_security(schema: Schema, settings: Settings, as_json: bool) -> None:
    import json

    from mbgw.cli import security
    found = security.report(schema, settings)
    if as_json:
        click.echo(json.dumps(found, indent=2))
    else:
        for line in security.text(found):
            click.echo(line)


def _show_scenarios(settings: Settings, name: str | None) -> None:
    shown = [sc for sc in settings.scenarios if name is None or sc.name == name]
    if name is not None and not shown:
        names = ", ".join(sc.name for sc in settings.scenarios)
        raise click.BadParameter(f"no scenario {name!r} in {settings.path}"
                                 + (f" (scenarios: {names})" if names else ""),
                                 param_hint="NAME")
    for number, sc in enumerate(shown):
        if number:
            click.echo()
        for line in scenario_text.block(sc.fields()):
            click.echo(line)


def _show_lines(settings: Settings, name: str | None, separate: bool = True) -> None:
    shown = [line for line in settings.lines if name is None or line.name == name]
    if name is not None and not shown:
        names = ", ".join(line.name for line in settings.lines)
        raise click.BadParameter(f"no line {name!r} in {settings.path}"
                                 + (f" (lines: {names})" if names else ""), param_hint="NAME")
    for number, line in enumerate(shown):
        if separate or number:
            click.echo()
        click.echo("[[line]]")
        for key, value in line_file.line_fields(line).items():
            click.echo(f"{key} = {dump_value(value)}")


def _show_routes(schema: Schema, settings: Settings, separate: bool = True) -> None:
    """The [[route]] tables, then the implicit routes in force beside them (when the file
    would start: else only the tables)."""
    for number, route in enumerate(settings.routes):
        if separate or number:
            click.echo()
        click.echo("[[route]]")
        for key, value in line_file.route_fields(route).items():
            click.echo(f"{key} = {dump_value(value)}")
    try:
        cfg = checks.check_file(schema, settings)
    except (ConfigError, click.ClickException):
        return
    implicit = implicit_routes(cfg) if settings.mode in LINE_MODES else ()
    if implicit and (separate or settings.routes):
        click.echo()
    for route in implicit:
        face = f"from {route.face}: " if route.face != TCP_FACE else ""
        click.echo(f"# implicit ({route.label}): {face}units "
                   f"{number_list_text(route.units)} -> {route.target}"
                   + (f" offset {route.offset}" if route.offset else "")
                   + (f" address {route.address}" if route.address is not None else ""))


def _read_checked(ctx, schema: Schema, path: Path, words) -> tuple[str, dict, Settings]:
    """The file's text, its data and its checked settings (the factory file's when there is
    none yet); a file that does not pass its check stops the edit."""
    try:
        text = read_text(path)
    except FileNotFoundError:
        text = factory_text(schema)
    except PermissionError:
        raise _permission_failure(ctx, path, "read", words) from None
    try:
        data = parse(path, text)
        return text, data, check(schema, path, data)
    except ConfigFileError as err:
        group = ctx.parent
        while group.parent is not None and group.command is not config:
            group = group.parent
        raise Failure(f"{err}\nmbgw: fix the file first (or start again: "
                      f"{_command_line(group, 'default', *_file_words(ctx, path))})") \
            from None


def _change(ctx, path: Path, words, change, shown: bool = True) -> None:
    """Read the file (or start from the factory file), make `change(schema, settings, data)`
    -> {key: value}, check the whole result, write it atomically, say what changed (its
    value too when `shown`)."""
    schema = schema_of(ctx)
    text, data, settings = _read_checked(ctx, schema, path, words)
    try:
        changes = change(schema, settings, data)
        new_data = apply_changes(data, schema, changes)
        pending = _start_check(schema, path, new_data)
    except ConfigError as err:
        raise _refused(path, err) from None
    new_mode = changes.get(MODE_KEY, settings.mode)
    new_text = edit(text, schema, new_mode, changes)
    if tomllib.loads(new_text) != new_data:          # the editor's own check
        raise Failure(f"{path}: could not edit the file in place; nothing written")
    labels = {name: schema.label(name) if name == MODE_KEY or name in schema.keys else name
              for name in changes}
    _write(ctx, path, new_text, words, ", ".join(labels.values()))
    for name, value in changes.items():
        label = labels[name]
        if value is REMOVE:
            click.echo(f"{path}: {label} back to its default")
        elif not shown:
            click.echo(f"{path}: {label} set")
        else:
            click.echo(f"{path}: {label} = {dump_value(value)}")
    _warn_pending(path, pending)
    if text != new_text and not pending:
        _say_how_to_apply(path)


def _start_check(schema: Schema, path: Path, data: dict) -> list[str]:
    """The checks of the file and of `mbgw run` (mbgw.cli.checks) on an edit's result:
    raises ConfigError on a problem the edit must not write; the keys that do not go
    together yet (another `set` mends them)."""
    wrong, pending = checks.refusals(schema, check(schema, path, data))
    if wrong:
        raise ConfigFileError(path, [*wrong, "nothing written"])
    return pending


def _refused(path: Path, err: ConfigError) -> Failure:
    lines = str(err).splitlines()
    return Failure("\n".join(line if line.startswith(str(path)) else f"{path}: {line}"
                             for line in lines))


def _warn_pending(path: Path, pending: list[str]) -> None:
    """Written, but the service would not start it, nor take it on a reload, yet."""
    for problem in pending:
        click.echo(f"mbgw: warning: {path}: {problem}", err=True)
    if pending:
        click.echo(f"mbgw: warning: {path}: mbgw run and systemctl reload refuse the file "
                   f"until this is set; mbgw check-config checks it", err=True)


@config.command("set")
@_file_options
@click.argument("group", type=click.Choice(GROUPS))
@click.argument("param")
@click.argument("values", nargs=-1, required=True)
@click.pass_context
def set_(ctx, config_path: Path, instance: str | None, group: str, param: str,
         values: tuple) -> None:
    """Set PARAM of GROUP with the guide's syntax, e.g.

    \b
      mbgw config set serial stout 700
      mbgw config set serial format 8e1
      mbgw config set serial mode master       (clears net.authip and net.slaveid)
      mbgw config set serial mode rtu          (the protocol)
      mbgw config set net authip 1 192.168.1.5 (entry 1..8; 0.0.0.0 clears it)
      mbgw config set net slaveid 1 8 1 0 192.168.0.30   (master: FS LS FR M IP; FS 0 clears)
      mbgw config set net exception on
      mbgw config set general location Pump house 3   (the guide's set location)
    """
    path = _path(ctx, config_path, instance)
    words = [group, param, *values, *_file_words(ctx, path)]
    _change(ctx, path, words,
            lambda schema, settings, data: changes_for_set(schema, settings, group,
                                                                      param,
                                                              list(values)))


@config.command("unset")
@_file_options
@click.argument("group", type=click.Choice(GROUPS))
@click.argument("param")
@click.pass_context
def unset(ctx, config_path: Path, instance: str | None, group: str, param: str) -> None:
    """Take PARAM out of the file: it goes back to its built-in default.  Works on a
    misspelt key too."""
    path = _path(ctx, config_path, instance)
    words = [group, param, *_file_words(ctx, path)]
    if group == "serial" and param == MODE_KEY:
        _change(ctx, path, words, lambda schema, settings, data: changes_for_set(
            schema, settings, group, param, [schema.default_mode]))
    else:
        _unset(ctx, path, words, group, param)


def _unset(ctx, path: Path, words, group: str, param: str) -> None:
    """Works on the text, even when the key is unknown (a typo) or its value is bad."""
    schema = schema_of(ctx)
    try:
        text = read_text(path)
    except FileNotFoundError:
        click.echo(f"{path}: no such file: {group}.{param} is at its default")
        return
    except PermissionError:
        raise _permission_failure(ctx, path, "read", words) from None
    data = _parse(path, text)
    group_data = data.get(group)
    content = group_data if isinstance(group_data, dict) else {}
    if param not in content:
        click.echo(f"{path}: {group}.{param} is not set: it is at its default")
        return
    serial_data = data.get("serial")
    serial = serial_data if isinstance(serial_data, dict) else {}
    known = schema.find(group, param)
    commented = default_line(schema, known.name,
                                         str(serial.get(MODE_KEY, ""))) if known else None
    new_text = set_line(text, group, param, None, commented)
    new_data = _parse(path, new_text)
    if param in new_data.get(group, {}):
        raise Failure(f"{path}: could not edit the file in place; nothing written")
    try:
        write_atomic(path, new_text)
    except PermissionError:
        raise _permission_failure(ctx, path, "write", words) from None
    _audit(ctx, path, f"{group}.{param}")
    click.echo(f"{path}: {group}.{param} back to its default")
    try:
        wrong, pending = checks.refusals(schema, check(schema, path, new_data))
        if wrong or pending:
            raise ConfigFileError(path, [*wrong, *pending])
    except ConfigFileError as err:
        raise Failure(f"{err}\n(the file still has these problems)") from None
    _say_how_to_apply(path)


def _parse(path: Path, text: str) -> dict:
    try:
        return parse(path, text)
    except ConfigFileError as err:
        raise Failure(str(err)) from None


SERVICE_GROUP = "mbgw"       # the service's user and group (debian/mbgw.sysusers)


@config.command("password")
@_file_options
@click.argument("role", type=click.Choice(["admin", "user"]))
@click.option("--stdin", "from_stdin", is_flag=True,
              help="Read the password from the first line of standard input (scripts, tests).")
@click.pass_context
def password(ctx, config_path: Path, instance: str | None, role: str, from_stdin: bool) -> None:
    """Set the web console's password of ROLE (admin: changes; user: reads), prompted twice;
    the file keeps its salted scrypt hash (web.admin-password, web.user-password), which
    `config show` never shows."""
    from mbgw.web.passwords import hash_password
    path = _path(ctx, config_path, instance)
    text = _read_password(from_stdin)
    try:
        stored = hash_password(text)
    except ConfigError as err:
        raise Failure(str(err)) from None
    _change(ctx, path, ["password", role, *_file_words(ctx, path)],
            lambda schema, settings, data: {f"{role}-password": stored}, shown=False)
    _keep_from_others(path)


def _keep_from_others(path: Path) -> None:
    """A file with password hashes is not for every local user: no access for others; its
    group becomes the service's (mbgw, which reads it) when root sets the password."""
    import grp
    import os
    import stat
    try:
        group = grp.getgrnam(SERVICE_GROUP).gr_gid if os.geteuid() == 0 else None
    except KeyError:
        group = None
    try:
        if group is not None:
            os.chown(path, -1, group)
        os.chmod(path, stat.S_IMODE(os.stat(path).st_mode) & ~0o007 | 0o040 * (group is not None))
    except OSError as err:
        raise Failure(f"{path}: the hash is written, but the file could not be closed to "
                      f"other users: {err.strerror}") from None


def _read_password(from_stdin: bool) -> str:
    import getpass
    import sys
    if from_stdin:
        return sys.stdin.readline().rstrip("\r\n")
    first = getpass.getpass("New password: ")
    if getpass.getpass("Again: ") != first:
        raise Failure("the passwords differ; nothing written")
    return first


@config.command("default")
@_file_options
@click.pass_context
def default(ctx, config_path: Path, instance: str | None) -> None:
    """Write the factory defaults: the guide's `set default`.  Every key is listed with its
    help, commented out at its built-in default; the device is /dev/ttyUSB0."""
    path = _path(ctx, config_path, instance)
    _write(ctx, path, factory_text(schema_of(ctx)), _file_words(ctx, path),
           "factory defaults")
    click.echo(f"{path}: factory defaults written")
    _say_how_to_apply(path)



# --- mbgw config scenario add|remove ----------------------------------------------------------

@config.group("scenario")
def config_scenario() -> None:
    """Add and remove the [[scenario]] tables of the configuration file: requests the gateway
    sends on its own (see mbgw.toml(5), SCENARIOS).  Checked like the file; the running
    service takes them on `systemctl reload mbgw`."""


@config_scenario.command("add")
@_file_options
@click.argument("name")
@click.argument("keys", nargs=-1, required=True, metavar="KEY=VALUE...")
@click.pass_context
def scenario_add(ctx, config_path: Path, instance: str | None, name: str, keys: tuple) -> None:
    """Add scenario NAME with the keys of a [[scenario]] table: slave (serial) or server
    and unit (TCP), function, address, quantity, table, cycle (ms) or trigger=change, and
    retries, stale-after, enabled, send-unwritten; function 23: read-address,
    read-quantity, read-table, write-address, write-quantity, write-table.  See
    mbgw.toml(5), SCENARIOS.  E.g.

    \b
      mbgw config scenario add boiler-temps slave=45 function=3 address=1000 quantity=10 \\
          table=0 cycle=3000
      mbgw config scenario add valve server=192.168.10.45 function=5 address=7 \\
          table=100.0 trigger=change
    """
    path = _path(ctx, config_path, instance)
    words = ["scenario", "add", name, *keys, *_file_words(ctx, path)]

    def change(text: str, data: dict) -> str:
        fields = scenario_text.parse_words(keys)
        if "name" in fields:
            raise ConfigError("name: give it once, as NAME, not as a KEY=VALUE")
        scenario = scenario_config.parse_scenario({"name": name, **fields}, f"scenario {name}")
        if any(e.get("name") == name for e in data.get(SCENARIO_KEY, [])
               if isinstance(e, dict)):
            raise ConfigError(f"scenario {name}: already there (mbgw config scenario remove "
                              f"{name} first)")
        return scenario_text.add(text, scenario.fields())
    _edit_scenarios(ctx, path, words, change, f"scenario {name} added")


@config_scenario.command("remove")
@_file_options
@click.argument("name")
@click.pass_context
def scenario_remove(ctx, config_path: Path, instance: str | None, name: str) -> None:
    """Take scenario NAME out of the file."""
    path = _path(ctx, config_path, instance)
    words = ["scenario", "remove", name, *_file_words(ctx, path)]

    def change(text: str, data: dict) -> str:
        new_text = scenario_text.remove(text, name)
        if new_text is None:
            names = [e.get("name") for e in data.get(SCENARIO_KEY, []) if isinstance(e, dict)]
            raise ConfigError(f"no scenario {name!r}" +
                              (f" (scenarios: {', '.join(map(str, names))})" if names else ""))
        return new_text
    _edit_scenarios(ctx, path, words, change, f"scenario {name} removed")


def _edit_scenarios(ctx, path: Path, words, change, done: str) -> None:
    """Read and check the file (or start from the factory file), new_text = change(text,
    data), check the result as a whole, write it atomically."""
    schema = schema_of(ctx)
    text, data, _ = _read_checked(ctx, schema, path, words)
    try:
        new_text = change(text, data)
        pending = _start_check(schema, path, parse(path, new_text))
    except ConfigError as err:
        raise _refused(path, err) from None
    _write(ctx, path, new_text, words, done)
    click.echo(f"{path}: {done}")
    scenarios = check(schema, path, parse(path, new_text)).scenarios
    for warning in scenario_config.overlaps(scenarios):
        click.echo(f"mbgw: warning: {path}: {warning}", err=True)
    _warn_pending(path, pending)
    if not pending:
        _say_how_to_apply(path)
