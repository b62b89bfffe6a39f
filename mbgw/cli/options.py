"""What every command shares: the one way a command fails (Failure, EX_CONFIG), the mode
commands' class (ModeCommand), turning a configuration error into a usage error naming the
option, and stacking options.  The option groups are in serial_options, table_options,
tls_options, web_options and daemon_options."""
from collections.abc import Callable

import click

from mbgw.config import model
from mbgw.config.cache import CacheRule, parse_cache
from mbgw.errors import ConfigError


class Failure(click.ClickException):
    """Printed as "mbgw: ..." lines on stderr; exit status 1, or `exit_code`."""

    def __init__(self, message: str, exit_code: int = 1) -> None:
        super().__init__(message)
        self.exit_code = exit_code      # type: ignore[misc]  # click's is a ClassVar

    def show(self, file=None) -> None:
        for line in self.format_message().splitlines():
            click.echo(f"mbgw: {line}", file=file, err=file is None)


EX_CONFIG = 78                     # sysexits.h; the units do not restart on it


META_FILE = "mbgw.config_file"     # ctx.meta: the file the running mode command took values from


class ModeCommand(click.Command):
    """A mode command (slave, master, transparent): make_config(**params) builds the
    settings its daemon starts with (mbgw.cli.checks).  A value from its configuration file
    that a check of the options refuses (the CRL and the CA, checked together) is the file's
    problem: EX_CONFIG, naming the file and the key, not a usage error."""
    make_config: Callable | None = None
    # (the file in use, its values by parameter name) for -h, or None (mbgw.cli.config_option)
    file_values: Callable[[click.Context], tuple[object, dict] | None] | None = None

    def format_options(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The built-in defaults (not the file's, which click's default_map would show), and
        beside each the value the file in use sets instead."""
        file_values = getattr(type(self), "file_values", None)
        found = file_values(ctx) if file_values is not None else None
        saved, ctx.default_map = ctx.default_map, None
        try:
            rows = []
            for param in self.get_params(ctx):
                record = param.get_help_record(ctx)
                if record is None or isinstance(param, click.Argument):
                    continue
                if found is not None and param.name in found[1]:
                    shown = _shown(found[1][param.name])
                    if shown != _shown(param.default):
                        record = (record[0], f"{record[1]}  [{found[0]} sets {shown}]")
                rows.append(record)
        finally:
            ctx.default_map = saved
        if rows:
            with formatter.section("Options"):
                formatter.write_dl(rows)

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, args)
        except click.BadParameter as err:
            path, param, root = ctx.meta.get(META_FILE), err.param, ctx.find_root().command
            if path is None or param is None or param.name is None or \
                    ctx.get_parameter_source(param.name) \
                    is not click.core.ParameterSource.DEFAULT_MAP:
                raise
            from mbgw.config.schema import Schema
            key = Schema(root).key_of_param(param) if isinstance(root, click.Group) else None
            label = key.label if key is not None else param.name
            raise Failure(f"{path}: {label}: {err.message}", EX_CONFIG) from None


def _shown(value) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, list | tuple):
        return " ".join(map(_shown, value)) or "(empty)"
    return str(value)


def convert(param_name: str | None, build):
    """Run a config constructor, turning ConfigError into a usage error (exit 2) naming the
    option: the error's key when it carries one (the message then without the key, which
    the hint says), else param_name (None: no option in particular)."""
    try:
        return build()
    except ConfigError as err:
        if err.key is None:
            raise click.BadParameter(str(err), param_hint=param_name) from None
        message = str(err)
        for said in (f"{err.key}: ", f"{err.key} "):
            message = message.removeprefix(said)
        raise click.BadParameter(message, param_hint=f"'--{err.key}'") from None


class CacheType(click.ParamType):
    """--cache: "ttl=MS,serve-stale=MS" or "off"; in the file an inline table (or false)."""
    name = "cache"
    takes_table = True      # the file's value is a TOML table (mbgw.config.values)

    def convert(self, value, param, ctx):
        if value is None or isinstance(value, CacheRule):
            return value
        try:
            return parse_cache(value)
        except ConfigError as err:
            self.fail(str(err), param, ctx)


def parser(parse):
    def callback(ctx, param, value):
        return convert(f"'{param.opts[0]}'", lambda: parse(value))
    return callback


def parse_authip(values) -> tuple:
    """--authip: IP addresses (an IPv4-mapped IPv6 one as its IPv4 address)."""
    return tuple(str(model.parse_ip("authip", v)) for v in values)


def parse_bind(value):
    """--bind: an IP address (the listeners bind it as given, scope id included)."""
    if value is not None:
        try:
            model.parse_ip("bind", value)
        except ConfigError:
            raise ConfigError(f"{value!r} is not an IP address") from None
    return value


def authip_option(help: str):
    """--authip, the client addresses a mode's listeners accept; help: which listeners."""
    return click.option("--authip", multiple=True, metavar="IP", callback=parser(parse_authip),
                        help=help)


def bind_option(help: str = "Listen on this IP address only [default: all, IPv4 and IPv6]."):
    """--bind, the one address a mode's listeners bind."""
    return click.option("--bind", metavar="ADDR", default=None, callback=parser(parse_bind),
                        help=help)


def stack(*decorators):
    def apply(function):
        for decorator in reversed(decorators):
            function = decorator(function)
        return function
    return apply


def face_port_options(when: str = ""):
    """The Modbus TCP face's other listeners, on bind's addresses with its routes, authip and
    firewall (rule listener "udp", "rtu"); when: the mode's condition, said in the help."""
    return stack(
        click.option("--udp-port", type=click.IntRange(*model.MDBPORT_RANGE), default=0,
                     show_default=True,
                     help=f"Modbus/UDP port the Modbus TCP face listens on{when}, one "
                          f"request a datagram (0: none)."),
        click.option("--rtu-port", type=click.IntRange(*model.MDBPORT_RANGE), default=0,
                     show_default=True,
                     help=f"RTU-over-TCP port (\"TCP with CRC\": RTU frames in a TCP "
                          f"stream) the Modbus TCP face listens on{when} (0: none)."),
    )
