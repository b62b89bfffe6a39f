"""Running a mode command's daemon, the same for both modes: the settings from the options,
logging, SIGHUP applying the configuration file again, and a device or port that cannot be
had turned into the command's failure."""
import dataclasses
from collections.abc import Callable

from mbgw.cli.config import config_file, reloader
from mbgw.cli.options import Failure, web_config
from mbgw.errors import ConfigError, SerialError


def run_daemon(run: Callable, make_config: Callable, options: dict) -> None:
    """run(cfg, reconfigure) until it stops, cfg = make_config(**options); reconfigure() is
    what SIGHUP applies: the configuration file again, command-line options kept (None when
    the settings did not come from a file)."""
    from mbgw.ops import log
    from mbgw.ops.service import ListenError

    path = config_file()
    _hand_keys_to_web_console()
    cfg = _from_file(_with_web(make_config, options), path)
    log.setup(options["log_level"])
    reload = reloader()

    def reconfigure():
        new = reload()
        new.pop("mode", None)
        log.setup(new["log_level"])
        return _from_file(_with_web(make_config, new), path)

    try:
        run(cfg, reconfigure if reload else None)
    except SerialError as err:
        raise Failure(err.strerror or str(err)) from None
    except (ListenError, ConfigError) as err:
        raise Failure(str(err)) from None


def _hand_keys_to_web_console() -> None:
    """The console edits the file with the keys of these mode commands (web never imports
    cli)."""
    import click

    from mbgw.web.config_api import use_commands
    ctx = click.get_current_context()
    root = ctx.find_root().command
    if isinstance(root, click.Group):
        use_commands(root, [name for name in ctx.params if ctx.get_parameter_source(name) in (
            click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)])


def _with_web(make_config: Callable, options: dict):
    """The mode's settings with [web] and [net] request-timeout: the options every mode has
    alike."""
    options = dict(options)
    web = web_config(options)
    request_timeout = options.pop("request_timeout")
    web = dataclasses.replace(web, request_timeout_ms=request_timeout)
    return dataclasses.replace(make_config(**options), web=web,
                               request_timeout_ms=request_timeout)


def _from_file(cfg, path):
    return cfg if path is None else dataclasses.replace(cfg, config_file=str(path))
