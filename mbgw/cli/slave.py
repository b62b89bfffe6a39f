"""The `mbgw slave` command: Modbus TCP clients reach the slaves on a serial line."""
import click

from mbgw.cli.daemon_options import daemon_options, gateway_unit_option, scenario_tcpto_option
from mbgw.cli.lines import with_lines
from mbgw.cli.options import (
    CacheType,
    ModeCommand,
    authip_option,
    bind_option,
    convert,
    face_port_options,
    parser,
)
from mbgw.cli.run import run_daemon
from mbgw.cli.serial_options import (
    demotion,
    demotion_options,
    interframe_option,
    serial_config,
    serial_options,
)
from mbgw.cli.table_options import table_config, table_options, table_switch
from mbgw.cli.tls_options import tls_config, tls_options, upstream_tls_config, upstream_tls_options
from mbgw.config import model
from mbgw.config.number_list import number_list_text, parse_number_list
from mbgw.config.schema import TableOption


def _parse_units(value) -> tuple[int, ...]:
    return parse_number_list("table-units", value, 1, 255)


@click.command(cls=ModeCommand)
@serial_options
@interframe_option
@click.option("--slaveid", type=click.IntRange(*model.SLAVEID_RANGE),
              default=model.SlaveConfig.slaveid, show_default=True,
              help="0: the TCP unit id is the serial address; 1..247: force this address.")
@click.option("--exception/--no-exception", default=model.SlaveConfig.exception,
              show_default=True,
              help="Answer exception 0x0B when a slave does not reply, 0x0A when the line "
                   "cannot be reached, instead of staying silent.")
@authip_option("Client address allowed to connect (repeat, at most 8; none: anyone).")
@click.option("--mdbport", type=click.IntRange(*model.MDBPORT_RANGE),
              default=model.SlaveConfig.mdbport, show_default=True,
              help="Modbus TCP port to listen on (0: none, Modbus/TCP Security only).")
@face_port_options()
@bind_option()
@click.option("--max-connections", type=click.IntRange(*model.MAX_CONNECTIONS_RANGE),
              default=model.SlaveConfig.max_connections, show_default=True,
              help="Simultaneous TCP clients (closed ones do not count); a newcomer closes an "
                   "idle one that never sent a request, else the least recently active one "
                   f"quiet for {model.ACTIVE_WINDOW_S} s, else it is refused.")
@click.option("--max-connections-per-ip", type=click.IntRange(*model.MAX_CONNECTIONS_PER_IP_RANGE),
              default=model.SlaveConfig.max_connections_per_ip, show_default=True,
              help="Simultaneous TCP clients from one address (0: no limit); one more from "
                   "that address is refused.")
@click.option("--retries", type=click.IntRange(*model.RETRIES_RANGE),
              default=model.SlaveConfig.retries, show_default=True,
              help="Times a request is repeated after no valid reply.")
@click.option("--late-window", type=click.IntRange(*model.LATE_WINDOW_RANGE), default=None,
              metavar="MS",
              help="After a request to a serial address timed out, its next request waits "
                   "until the late reply has come (it is dropped) or the line has been quiet "
                   "this long past the timeout; other addresses are served meanwhile.  0: no "
                   "wait.  0..65535 ms [default: stout].")
@click.option("--cache", type=CacheType(), default=None, metavar="ttl=MS,serve-stale=MS",
              help="Reads (FC 1-4) that share one transaction: a read identical to one "
                   "waiting or on the line gets its answer; one within data read less than "
                   "ttl ms ago is answered from memory; after its own transaction failed, "
                   "from data less than serve-stale ms old.  A write drops the data it "
                   "overlaps before its reply is forwarded.  0..3600000 ms each "
                   "[default: off].")
@click.option("--turnaround", type=click.IntRange(*model.TURNAROUND_RANGE),
              default=model.SlaveConfig.turnaround_ms,
              show_default=True, metavar="MS",
              help="Pause on the line after a broadcast (unit 0), before the next request.")
@scenario_tcpto_option
@demotion_options
@table_switch
@click.option("--direct/--no-direct", "table_direct", cls=TableOption, key="direct",
              default=model.TableConfig.direct, show_default=True,
              help="With --table: only the units of --table-units reach the table, the others "
                   "go to the serial line (direct messaging).  --no-direct: every unit reaches "
                   "the table (a Modbus TCP server of local data; unit 0 is a broadcast write, "
                   "not answered).")
@click.option("--table-units", cls=TableOption, key="units", metavar="LIST",
              default=number_list_text(model.DEFAULT_TABLE_UNITS), show_default=True,
              callback=parser(_parse_units),
              help="With --table and --direct: the TCP unit ids that reach the table, e.g. "
                   "247-254 or 1,5,200-210 (1..255).")
@table_options
@tls_options
@upstream_tls_options
@daemon_options
@gateway_unit_option
@click.option("--shortcut/--no-shortcut", default=model.SlaveConfig.shortcut, hidden=True,
              help="Put a request that finds the line idle on it from C (for diagnosis).")
def slave(**options) -> None:
    """Slave mode: Modbus TCP clients reach the slaves on a serial line."""
    from mbgw.gateway.daemon import run_slave_mode

    run_daemon(run_slave_mode, slave_config, options)


def slave_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout, silence,
                 ascii_timeout, nocheck, dtr, rts, cts, xonxoff, interframe_silence, slaveid,
                 exception, authip, mdbport, bind, max_connections, max_connections_per_ip,
                 retries, turnaround, control, metrics, log_level=None, shortcut=True,
                 down_after=model.DEFAULT_DOWN_AFTER,
                 probe_interval=model.DEFAULT_PROBE_INTERVAL_MS, firewall=None, scenarios=(),
                 lines=(), routes=(), monitors=(), devices=(),
                 tls_port=model.DEFAULT_TLS_PORT, tls_cert=None, tls_key=None, tls_ca=None,
                 tls_require_role=True, tls_crl=None, tcpto=model.DEFAULT_TCPTO_MS,
                 late_window=None, gateway_unit=0, udp_port=0, rtu_port=0, cache=None,
                 **table_settings) -> model.SlaveConfig:
    serial = serial_config(device, protocol, baudrate, line_format,
                           interface, rtsdelays, stout, silence, ascii_timeout, nocheck, dtr,
                           rts, cts, xonxoff, interframe_silence)
    upstream_tls = upstream_tls_config(table_settings)
    table = table_config(**table_settings)
    tls = tls_config(tls_port, tls_cert, tls_key, tls_ca, tls_require_role, tls_crl)
    cfg = convert(None, lambda: model.SlaveConfig(
        serial=serial, slaveid=slaveid, exception=exception, authip=authip, mdbport=mdbport,
        udp_port=udp_port, rtu_port=rtu_port, upstream_tls=upstream_tls,
        bind=bind, max_connections=max_connections,
        max_connections_per_ip=max_connections_per_ip, retries=retries,
        turnaround_ms=turnaround, late_window_ms=late_window, cache=cache, control=control,
        metrics=metrics, shortcut=shortcut,
        demotion=demotion(down_after, probe_interval), table=table, tcpto_ms=tcpto,
        firewall=firewall, scenarios=scenarios, tls=tls, gateway_unit=gateway_unit))
    return with_lines(cfg, "slave", lines, routes, monitors, devices)

slave.make_config = slave_config
