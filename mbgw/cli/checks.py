"""The one check of what a mode command would start: its parameters built into its settings
(the mode's make_config, with [web]), then what the start itself would refuse
(mbgw.ops.preflight).  `mbgw run` and the mode commands at start, a reload, check-config,
`config set` and the web console (handed check_file) all go through it, so that whatever the
start refuses each of them refuses first, naming the key."""
import dataclasses
import re

import click

from mbgw.cli.mqtt_options import mqtt_config
from mbgw.cli.options import ModeCommand
from mbgw.cli.web_options import web_config
from mbgw.config.file import Settings, resolve, with_file
from mbgw.config.model import DEFAULT_LOCATION, DEFAULT_REQUEST_TIMEOUT_MS
from mbgw.config.schema import Schema
from mbgw.errors import ConfigError, ConfigFileError
from mbgw.ops import preflight

# a message that names its key already: "tls.key: ", "net.authip[2]: ", "scenario boiler: ",
# "line meters.baudrate: ", "route 2.units: "
_LABEL = re.compile(r"^([a-z]+\.[a-z-]+(\[\d+\])?|scenario [^:]+|(line|route|device) [^:]+"
                    r"|slaveid '[^']*'): ")
_FLAG = re.compile(r"--[a-z][a-z-]*")


def build(make_config, params: dict):
    """make_config(**params) with the [web] and [mqtt] settings and [net] request-timeout,
    which every mode shares.  Raises
    click.BadParameter (naming the option) when the values do not go together."""
    options = dict(params)
    options.pop("log_format", None)       # how the daemon logs, not a mode's setting
    web = web_config(options)
    mqtt = mqtt_config(options)
    location = options.pop("location", DEFAULT_LOCATION)
    request_timeout = options.pop("request_timeout", DEFAULT_REQUEST_TIMEOUT_MS)
    web = dataclasses.replace(web, request_timeout_ms=request_timeout)
    return dataclasses.replace(make_config(**options), web=web, mqtt=mqtt,
                               location=location,
                               request_timeout_ms=request_timeout)


def problems(schema: Schema, command: click.Command, params: dict,
             make_config=None) -> tuple[object, list[str]]:
    """(the settings, or None when they cannot be built; every problem, "group.key: why"),
    built by make_config, by default the command's."""
    if make_config is None:
        assert isinstance(command, ModeCommand) and command.make_config is not None
        make_config = command.make_config
    try:
        cfg = build(make_config, params)
    except click.BadParameter as err:
        return None, [named(schema, command, err)]
    except ConfigError as err:
        return None, [str(err)]
    return cfg, preflight.problems(cfg)


def check_file(schema: Schema, settings: Settings, given=()):
    """The settings a file starts (its mode's), when `mbgw run` would start them: raises
    ConfigFileError listing the problems, each naming the file and the key.  `given`: see
    mbgw.config.file.resolve."""
    params = resolve(schema, settings, given=given)
    cfg, found = problems(schema, schema.commands[settings.mode], params)
    if found:
        raise ConfigFileError(settings.path, [with_file(p, settings.path) for p in found])
    return cfg


def named(schema: Schema, command: click.Command, err: click.BadParameter) -> str:
    """A make_config refusal as "group.key: why": the key of the option its hint names."""
    message = err.message
    if _LABEL.match(message):
        return message
    param = param_of(command, err)
    key = schema.key_of_param(param) if param is not None else None
    return f"{key.label}: {message}" if key is not None else err.format_message()


def param_of(command: click.Command, err: click.BadParameter) -> click.Parameter | None:
    """The option a make_config refusal names first (its hint: "'--mdbport'")."""
    flag = _FLAG.search(str(err.param_hint or ""))
    if flag is None:
        return err.param
    return next((p for p in command.params if flag.group() in getattr(p, "opts", ())), None)


def refusals(schema: Schema, settings: Settings) -> tuple[list[str], list[str]]:
    """What `mbgw run` would refuse in a checked file, as `mbgw config set` weighs it:
    (what is wrong in itself: a file a key names, an address; refused), (keys that do not
    go together yet, which setting another key mends, e.g. tls.cert before tls.key; written
    with a warning)."""
    try:
        params = resolve(schema, settings)
    except ConfigFileError as err:
        return [], err.problems
    cfg, found = problems(schema, schema.commands[settings.mode], params)
    found = [with_file(p, settings.path) for p in found]
    return ([], found) if cfg is None else (found, [])
