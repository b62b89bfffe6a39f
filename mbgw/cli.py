"""The mbgw command line.  Options carry the ACKSYS command names and defaults."""
import sys

import click

from mbgw import __version__, config
from mbgw.errors import ConfigError, SerialError

LOG_LEVELS = click.Choice(["debug", "info", "warning", "error"], case_sensitive=False)


def _convert(param_name: str, build):
    """Run a config constructor, turning ConfigError into a usage error (exit 2)."""
    try:
        return build()
    except ConfigError as err:
        raise click.BadParameter(str(err), param_hint=param_name) from None


def _parser(parse):
    def callback(ctx, param, value):
        return _convert(f"'{param.opts[0]}'", lambda: parse(value))
    return callback


def _parse_authip(values) -> tuple:
    return tuple(str(config.parse_ip("authip", v)) for v in values)


def _parse_metrics(value):
    if value is not None:
        from mbgw.metrics import parse_address
        parse_address(value)
    return value


def _stack(*decorators):
    def apply(function):
        for decorator in reversed(decorators):
            function = decorator(function)
        return function
    return apply


serial_options = _stack(
    click.option("--device", required=True, metavar="PATH",
                 help="Serial device, e.g. /dev/ttyUSB0."),
    click.option("--protocol", type=click.Choice(config.PROTOCOLS), default="rtu",
                 show_default=True, help="Modbus framing on the serial line."),
    click.option("--baudrate", type=click.IntRange(*config.BAUDRATE_RANGE), default=9600,
                 show_default=True, help="Line speed in bit/s, any rate from 50 to 4000000."),
    click.option("--format", "line_format", default="8n1", show_default=True,
                 callback=_parser(config.LineFormat.parse), metavar="NPS",
                 help="Data bits (7|8), parity (n|e|o|m|s: none, even, odd, mark, space), "
                      "stop bits (1|2)."),
    click.option("--interface", default="rs232", show_default=True,
                 callback=_parser(config.Interface.parse), metavar="KIND",
                 help="rs232, rs422, 'rs485 noecho' or 'rs485 echo' (the transceiver "
                      "hears its own frames; they are dropped)."),
    click.option("--rtsdelays", type=(click.IntRange(0, 255), click.IntRange(0, 255)),
                 default=(0, 0), show_default=True, metavar="BEFORE AFTER",
                 help="RS-485: ms between raising RTS and the first byte, and between the "
                      "last byte and dropping RTS, 0..255."),
    click.option("--stout", type=click.IntRange(*config.STOUT_RANGE),
                 default=config.DEFAULT_STOUT_MS, show_default=True, metavar="MS",
                 help="Time from the end of a request to the end of its answer, 1..65535 ms."),
    click.option("--silence", type=click.IntRange(0, 65535), default=0, show_default=True,
                 metavar="MS",
                 help="RTU end-of-frame silence in ms, 0..65535 (0: the standard 3.5 "
                      "characters, 1.75 ms above 19200 bit/s); shorter gaps stay inside "
                      "a frame."),
    click.option("--ascii-timeout", type=click.IntRange(1, 65535),
                 default=config.DEFAULT_ASCII_TIMEOUT_MS, show_default=True, metavar="MS",
                 help="ASCII: longest pause between two characters of a frame, 1..65535 ms."),
    click.option("--nocheck", is_flag=True, default=False, show_default=True,
                 help="Debugging only: forward serial replies unchecked (no CRC/LRC, "
                      "address or length control), as received until end of frame.  "
                      "[default: off]"),
)


# The operator's tools, the same in both modes: control socket, metrics, log level.
daemon_options = _stack(
    click.option("--control", metavar="PATH", default=None,
                 help="Control socket for mbgw status/trace [default: "
                      "$RUNTIME_DIRECTORY/mbgw.sock or /run/mbgw/mbgw.sock]."),
    click.option("--metrics", metavar="ADDR:PORT", default=None,
                 callback=_parser(_parse_metrics),
                 help="Serve Prometheus metrics on http://ADDR:PORT/metrics ([IPV6]:PORT; "
                      ":PORT for every address) [default: off]."),
    click.option("--log-level", type=LOG_LEVELS, default="info", show_default=True),
)


def _serial_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout,
                   silence, ascii_timeout, nocheck) -> config.SerialConfig:
    return _convert("'--baudrate'", lambda: config.SerialConfig(
        device=device, protocol=protocol, baudrate=baudrate, format=line_format,
        interface=interface, rtsdelays=tuple(rtsdelays), stout_ms=stout, silence_ms=silence,
        ascii_timeout_ms=ascii_timeout, nocheck=nocheck))


# -h as well as --help, on every command: click hands it down to the subcommands' contexts.
CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"]}


@click.group(context_settings=CONTEXT_SETTINGS)
@click.version_option(__version__, prog_name="mbgw")
def main() -> None:
    """mbgw: a Modbus gateway between Modbus TCP and a Modbus RTU/ASCII serial line."""


@main.command()
@serial_options
@click.option("--slaveid", type=click.IntRange(0, 247), default=0, show_default=True,
              help="0: the TCP unit id is the serial address; 1..247: force this address.")
@click.option("--exception/--no-exception", default=False, show_default=True,
              help="Answer exception 0x0B when a slave does not reply, 0x0A when the line "
                   "cannot be reached, instead of staying silent.")
@click.option("--authip", multiple=True, metavar="IP", callback=_parser(_parse_authip),
              help="Client address allowed to connect (repeat, at most 8; none: anyone).")
@click.option("--mdbport", type=click.IntRange(1, 65535), default=502, show_default=True,
              help="Modbus TCP port to listen on.")
@click.option("--bind", metavar="ADDR", default=None,
              help="Listen on this address only [default: all, IPv4 and IPv6].")
@click.option("--max-connections", type=click.IntRange(1, 1000), default=5, show_default=True,
              help="Simultaneous TCP clients; a newcomer closes the least recently active "
                   "idle one.")
@click.option("--retries", type=click.IntRange(0, 10), default=0, show_default=True,
              help="Times a request is repeated after no valid reply.")
@click.option("--turnaround", type=click.IntRange(0, 65535), default=config.DEFAULT_TURNAROUND_MS,
              show_default=True, metavar="MS",
              help="Pause on the line after a broadcast (unit 0), before the next request.")
@daemon_options
def slave(**options) -> None:
    """Slave mode: Modbus TCP clients reach the slaves on a serial line."""
    from mbgw import cli_config, daemon, log

    cfg = slave_config(**options)
    log.setup(options["log_level"])
    reload = cli_config.reloader()

    def reconfigure() -> config.SlaveConfig:
        """SIGHUP: the configuration file again, command-line options kept."""
        new = reload()
        new.pop("mode", None)
        log.setup(new["log_level"])
        return slave_config(**new)

    try:
        daemon.run_slave(cfg, reconfigure if reload else None)
    except SerialError as err:
        fatal(err.strerror)
    except daemon.ListenError as err:
        fatal(str(err))


def slave_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout,
                 silence, ascii_timeout, nocheck, slaveid, exception, authip, mdbport, bind,
                 max_connections, retries, turnaround, control, metrics,
                 log_level=None) -> config.SlaveConfig:
    serial = _serial_config(device, protocol, baudrate, line_format, interface, rtsdelays,
                            stout, silence, ascii_timeout, nocheck)
    return _convert("'--authip'", lambda: config.SlaveConfig(
        serial=serial, slaveid=slaveid, exception=exception, authip=authip, mdbport=mdbport,
        bind=bind, max_connections=max_connections, retries=retries, turnaround_ms=turnaround,
        control=control, metrics=metrics))


def fatal(message: str) -> None:
    click.echo(f"mbgw: {message}", err=True)
    sys.exit(1)


# The other commands live in their own modules and register themselves on `main`.
from mbgw import cli_config, cli_diag, cli_master  # noqa: E402
cli_master.register(main)   # master (before cli_config, which gives both modes --config)
cli_config.register(main)   # run, check-config, config; --config on the mode commands
cli_diag.register(main)     # status, clients, stats, trace
