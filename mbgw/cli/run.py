"""`mbgw run` and `mbgw check-config`, and running a mode command's daemon, the same for
every mode: the settings from the options, checked as check-config checks them
(mbgw.cli.checks), logging, SIGHUP applying the configuration file again, and a device or
port that cannot be had turned into the command's failure."""
import dataclasses
from collections.abc import Callable
from pathlib import Path

import click

from mbgw.cli import checks
from mbgw.cli.config_option import (
    META_MODE_FROM_FILE,
    config_file,
    load_settings,
    reloader,
    schema_of,
)
from mbgw.cli.file_options import file_options, file_path
from mbgw.cli.options import EX_CONFIG, META_FILE, Failure
from mbgw.config import scenario as scenario_config
from mbgw.config.file import click_problem
from mbgw.config.schema import Schema
from mbgw.errors import ConfigError, ConfigFileError, ListenError, SerialError
from mbgw.ops import preflight


def run_daemon(run: Callable, make_config: Callable, options: dict) -> None:
    """run(cfg, reconfigure) until it stops, cfg = make_config(**options); reconfigure() is
    what SIGHUP applies: the configuration file again, command-line options kept (None when
    the settings did not come from a file).  Settings that the start would refuse fail with
    exit status 78 (EX_CONFIG), naming the key; a device or port that cannot be had with 1."""
    from mbgw.ops import log

    path = config_file()
    ctx = click.get_current_context()
    schema = schema_of(ctx)
    _hand_keys_to_web_console(ctx)
    options = dict(options)
    log_format = options.pop("log_format", "text")
    cfg = _from_file(_start_settings(schema, ctx.command, make_config, options, path), path)
    log.setup(options["log_level"], log_format)
    reload = reloader()

    def reconfigure():
        new = reload()
        new.pop("mode", None)
        log_format = new.pop("log_format", "text")
        built, found = checks.problems(schema, ctx.command, new, make_config)
        if found:
            raise ConfigFileError(path, found)
        log.setup(new["log_level"], log_format)
        return _from_file(built, path)

    try:
        run(cfg, reconfigure if reload else None)
    except SerialError as err:
        raise Failure(err.strerror or str(err)) from None
    except ListenError as err:
        raise Failure(str(err)) from None
    except ConfigError as err:        # a file the checks passed, changed or gone since
        raise Failure(str(err), EX_CONFIG) from None


def _start_settings(schema: Schema, command: click.Command, make_config: Callable,
                    options: dict, path: Path | None):
    """The settings to start with; Failure (EX_CONFIG) listing what the start would refuse.
    Options that do not go together, given on the command line, are a usage error (2),
    naming the option."""
    try:
        cfg = checks.build(make_config, options)
    except click.BadParameter as err:
        if path is None or _given(checks.param_of(command, err)):
            raise
        raise Failure(f"{path}: {checks.named(schema, command, err)}", EX_CONFIG) from None
    found = preflight.problems(cfg)
    if found:
        raise Failure("\n".join(f"{path}: {p}" if path else p for p in found), EX_CONFIG)
    return cfg


def _given(param: click.Parameter | None) -> bool:
    """The option is the command line's (or the environment's), not the file's."""
    ctx = click.get_current_context()
    return param is not None and param.name is not None and ctx.get_parameter_source(
        param.name) in (click.core.ParameterSource.COMMANDLINE,
                        click.core.ParameterSource.ENVIRONMENT)


def _hand_keys_to_web_console(ctx: click.Context) -> None:
    """The console edits the file with the keys of these mode commands, and checks it as
    check-config does (web never imports cli)."""
    from mbgw.web.config_api import use_commands
    root = ctx.find_root().command
    if isinstance(root, click.Group):
        use_commands(root, [name for name in ctx.params if ctx.get_parameter_source(name) in (
            click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)],
            checks.check_file)


def _from_file(cfg, path):
    return cfg if path is None else dataclasses.replace(cfg, config_file=str(path))


@click.command("run", context_settings={"ignore_unknown_options": True,
                                        "allow_interspersed_args": False})
@file_options
@click.argument("args", nargs=-1, type=click.UNPROCESSED, metavar="[MODE OPTIONS]...")
@click.pass_context
def run(ctx: click.Context, config_path: Path, instance: str | None, args) -> None:
    """Start the mode the configuration file selects (serial.mode): what the mbgw service
    runs.  Options after the file options are the mode command's and win over the file,
    e.g. `mbgw run --log-level debug`.  Exit status 78 when the file is wrong."""
    path = file_path(ctx, config_path, instance)
    schema = schema_of(ctx)
    settings = load_settings(ctx, schema, path, exit_code=EX_CONFIG)
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
@file_options
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
    path = file or file_path(ctx, config_path, instance)
    schema = schema_of(ctx)
    settings = load_settings(ctx, schema, path, [path], exit_code=EX_CONFIG)
    try:
        checks.check_file(schema, settings)
    except ConfigFileError as err:
        raise Failure(str(err), EX_CONFIG) from None
    for warning in scenario_config.overlaps(settings.scenarios):
        click.echo(f"mbgw: warning: {path}: {warning}", err=True)
    click.echo(f"{path}: ok ({settings.mode} mode)")
