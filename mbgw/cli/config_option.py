"""The --config FILE option of the mode commands (slave, master, transparent): the file's
values become their defaults (click's default_map), the command line winning; and, for the
running mode command, the file it took them from and how SIGHUP reads it again.  Also what
every command that reads the file shares: its schema, and a file it may not read."""
import shlex
from pathlib import Path

import click

from mbgw.cli.options import EX_CONFIG, META_FILE, Failure, ModeCommand
from mbgw.config import line_file
from mbgw.config import schema as config_schema  # DEFAULT_PATH read at each call
from mbgw.config.file import SCENARIOS_PARAM, Settings, load, load_options
from mbgw.config.lines import LINE_MODES
from mbgw.config.schema import MODES, Schema
from mbgw.errors import ConfigError, ConfigFileError

META_MODE_FROM_FILE = "mbgw.mode_from_file"   # ctx.meta: `mbgw run` took the mode from it


def add_to_mode_commands(root: click.Group) -> None:
    """A --config FILE option on each mode command of `root`, with the hidden parameters the
    file's tables reach the command by."""
    ModeCommand.file_values = staticmethod(_file_values)
    for mode in MODES:
        command = root.commands.get(mode)
        if command is not None and not any(p.name == "config" for p in command.params):
            command.params.append(_mode_config_option())
            command.params.append(_scenarios_option())
            if mode in LINE_MODES and isinstance(command, ModeCommand):   # make_config's
                command.params += [_given_option(line_file.LINES_PARAM),
                                   _given_option(line_file.ROUTES_PARAM),
                                   _given_option(line_file.MONITORS_PARAM),
                                   _given_option(line_file.DEVICES_PARAM)]


def schema_of(ctx: click.Context) -> Schema:
    """The configuration file's keys as the commands of ctx's root define them (a lone
    command's own, when the root has no mode commands)."""
    root = ctx.find_root().command
    if not isinstance(root, click.Group) or not any(m in root.commands for m in MODES):
        root = click.Group(commands=[ctx.command])
    return Schema(root)


def command_line(ctx: click.Context, *words) -> str:
    """The command being run with these words, to suggest it again (with sudo)."""
    return shlex.join([*ctx.command_path.split(), *map(str, words)])


def permission_failure(ctx, path, doing: str, words, exit_code: int = 1) -> Failure:
    """The file may not be read or written (doing): run the same command as root."""
    return Failure(f"cannot {doing} {path}: permission denied; run it as root: "
                   f"sudo {command_line(ctx, *words)}", exit_code)


def load_settings(ctx: click.Context, schema: Schema, path: Path, words=(),
                  exit_code: int = 1) -> Settings:
    """The file's checked settings; a Failure (exit_code) when it cannot be read or is
    wrong."""
    try:
        return load(schema, path)
    except PermissionError:
        raise permission_failure(ctx, path, "read", words, exit_code) from None
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
    settings = load_settings(ctx, schema, Path(value), exit_code=EX_CONFIG)
    if (settings.lines or settings.routes or settings.monitors or settings.devices) and not any(
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
