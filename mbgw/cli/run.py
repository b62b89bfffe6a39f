"""Running a mode command's daemon, the same for both modes: the settings from the options,
checked as check-config checks them (mbgw.cli.checks), logging, SIGHUP applying the
configuration file again, and a device or port that cannot be had turned into the command's
failure."""
import dataclasses
from collections.abc import Callable
from pathlib import Path

import click

from mbgw.cli import checks
from mbgw.cli.config import EX_CONFIG, config_file, reloader, schema_of
from mbgw.cli.options import Failure
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
