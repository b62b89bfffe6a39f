"""The `mbgw slave` command: Modbus TCP clients reach the slaves on a serial line."""
import click

from mbgw.cli.options import (Failure, convert, daemon_options, parser, serial_config,
                              serial_options)
from mbgw.cli.config import reloader
from mbgw.config import model as config
from mbgw.errors import SerialError


def _parse_authip(values) -> tuple:
    return tuple(str(config.parse_ip("authip", v)) for v in values)



@click.command()
@serial_options
@click.option("--slaveid", type=click.IntRange(0, 247), default=0, show_default=True,
              help="0: the TCP unit id is the serial address; 1..247: force this address.")
@click.option("--exception/--no-exception", default=False, show_default=True,
              help="Answer exception 0x0B when a slave does not reply, 0x0A when the line "
                   "cannot be reached, instead of staying silent.")
@click.option("--authip", multiple=True, metavar="IP", callback=parser(_parse_authip),
              help="Client address allowed to connect (repeat, at most 8; none: anyone).")
@click.option("--mdbport", type=click.IntRange(1, 65535), default=502, show_default=True,
              help="Modbus TCP port to listen on.")
@click.option("--bind", metavar="ADDR", default=None,
              help="Listen on this address only [default: all, IPv4 and IPv6].")
@click.option("--max-connections", type=click.IntRange(1, 1000), default=5, show_default=True,
              help="Simultaneous TCP clients (closed ones do not count); a newcomer closes an "
                   "idle one that never sent a request, else the least recently active one "
                   f"quiet for {config.ACTIVE_WINDOW_S} s, else it is refused.")
@click.option("--max-connections-per-ip", type=click.IntRange(0, 1000),
              default=config.SlaveConfig.max_connections_per_ip, show_default=True,
              help="Simultaneous TCP clients from one address (0: no limit); one more from "
                   "that address is refused.")
@click.option("--retries", type=click.IntRange(0, 10), default=0, show_default=True,
              help="Times a request is repeated after no valid reply.")
@click.option("--turnaround", type=click.IntRange(0, 65535), default=config.DEFAULT_TURNAROUND_MS,
              show_default=True, metavar="MS",
              help="Pause on the line after a broadcast (unit 0), before the next request.")
@daemon_options
def slave(**options) -> None:
    """Slave mode: Modbus TCP clients reach the slaves on a serial line."""
    from mbgw.ops import log
    from mbgw.ops.service import ListenError
    from mbgw.slave.daemon import run_slave

    cfg = slave_config(**options)
    log.setup(options["log_level"])
    reload = reloader()

    def reconfigure() -> config.SlaveConfig:
        """SIGHUP: the configuration file again, command-line options kept."""
        new = reload()
        new.pop("mode", None)
        log.setup(new["log_level"])
        return slave_config(**new)

    try:
        run_slave(cfg, reconfigure if reload else None)
    except SerialError as err:
        raise Failure(err.strerror or str(err)) from None
    except ListenError as err:
        raise Failure(str(err)) from None


def slave_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout,
                 silence, ascii_timeout, nocheck, slaveid, exception, authip, mdbport, bind,
                 max_connections, max_connections_per_ip, retries, turnaround, control,
                 metrics, log_level=None) -> config.SlaveConfig:
    serial = serial_config(device, protocol, baudrate, line_format, interface, rtsdelays,
                            stout, silence, ascii_timeout, nocheck)
    return convert("'--authip'", lambda: config.SlaveConfig(
        serial=serial, slaveid=slaveid, exception=exception, authip=authip, mdbport=mdbport,
        bind=bind, max_connections=max_connections,
        max_connections_per_ip=max_connections_per_ip, retries=retries,
        turnaround_ms=turnaround, control=control, metrics=metrics))
