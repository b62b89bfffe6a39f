"""The `mbgw master` command: a Modbus master on the serial line reaches Modbus TCP servers.
Registered by mbgw.cli; it shares the serial options and the operator's tools (control
socket, metrics, log level) with slave mode."""
import click
from click.core import ParameterSource

from mbgw.cli.daemon_options import daemon_options, gateway_unit_option
from mbgw.cli.lines import with_lines
from mbgw.cli.options import (
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
from mbgw.cli.table_options import (
    parse_serial_functions,
    table_config,
    table_max_connections_option,
    table_options,
    table_switch,
)
from mbgw.cli.tls_options import tls_config, tls_options, upstream_tls_config, upstream_tls_options
from mbgw.config import model
from mbgw.config.lines import TCP_FACE
from mbgw.config.schema import TableOption
from mbgw.config.slaveid import MAX_RANGES, SlaveIdTable

SLAVE_MODE_ONLY = ("stout", "nocheck")


@click.command(cls=ModeCommand)
@serial_options
@interframe_option
@click.option("--slaveid", "slaveid", multiple=True, metavar='"FS LS FR M IP [tls]"',
              callback=parser(SlaveIdTable.parse),
              help="Serial addresses FS..LS go to the server at IP, as unit id FR + (address "
                   "- FS), or 0xFF when FR is 0; M=1 adds (address - FS) to the IP's last "
                   f"byte too.  Repeat for up to {MAX_RANGES} ranges; a line whose FS lies in "
                   "a range already defined replaces it (other overlaps are refused); FS=0 "
                   "clears the table.  A 6th word tls reaches the range's servers over TLS "
                   "(--tls-client-cert).")
@click.option("--tcpto", type=click.IntRange(*model.TCPTO_RANGE),
              default=model.MasterConfig.tcpto_ms, show_default=True, metavar="MS",
              help="Time for a transaction with a server, connecting included, 1..65535 ms.")
@click.option("--mdbport", type=click.IntRange(*model.PORT_RANGE),
              default=model.MasterConfig.mdbport, show_default=True,
              help="Modbus TCP port of the remote servers.")
@click.option("--exception/--no-exception", default=model.MasterConfig.exception,
              show_default=True,
              help="Answer exception 0x0B when a server does not reply within tcpto, 0x0A "
                   "when it cannot be reached, instead of staying silent.")
@click.option("--max-connections", type=click.IntRange(*model.MAX_CONNECTIONS_RANGE),
              default=model.MasterConfig.max_connections, show_default=True,
              help="Connections kept open to servers; one more closes the least recently "
                   "used.")
@authip_option("Client address allowed to connect to the table's server (--table-port and "
               "the TLS port; repeat, at most 8; none: anyone).")
@bind_option("The table's server listens on this IP address only [default: all, IPv4 and "
             "IPv6].")
@face_port_options(" (a route without from gives the daemon one)")
@upstream_tls_options
@demotion_options
@table_switch
@click.option("--table-address", cls=TableOption, key="address",
              type=click.IntRange(*model.TABLE_ADDRESS_RANGE),
              default=model.TableConfig.address, show_default=True, metavar="N",
              help="With --table: mbgw answers requests for serial address N (1..247) from "
                   "the table, as a serial slave; no --slaveid range may hold N.  0: the "
                   "table is reached only on --table-port.")
@click.option("--table-serial-functions", cls=TableOption, key="serial-functions",
              default=None, callback=parser(parse_serial_functions), metavar="LIST",
              help="Function codes the table's serial slave answers (--table-address), a list "
                   "of its own (VPGate 3.7) [default: --table-functions, which is then the "
                   "TCP clients' list only].")
@click.option("--table-port", cls=TableOption, key="port",
              type=click.IntRange(*model.PORT_RANGE),
              default=model.TableConfig.port, show_default=True,
              help="With --table: the TCP port where Modbus TCP clients reach the table.")
@table_max_connections_option(
    "With --table: TCP clients of the table at once (its TLS port's included); a newcomer "
    "beyond it takes the place of one that sent no request yet, or is refused.")
@table_options
@tls_options
@daemon_options
@gateway_unit_option
@click.pass_context
def master(ctx, **options) -> None:
    """Master mode: a Modbus master on the serial line reaches Modbus TCP servers."""
    from mbgw.gateway.daemon import run_master_mode

    for name in SLAVE_MODE_ONLY:
        if ctx.get_parameter_source(name) in (ParameterSource.COMMANDLINE,
                                              ParameterSource.ENVIRONMENT):
            raise click.BadParameter("applies to slave mode only", param_hint=f"'--{name}'")
    run_daemon(run_master_mode, master_config, options)


def master_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout, silence,
                  ascii_timeout, nocheck, dtr, rts, cts, xonxoff, interframe_silence, slaveid,
                  tcpto, mdbport, exception, max_connections, control, metrics, log_level=None,
                  down_after=model.DEFAULT_DOWN_AFTER,
                  probe_interval=model.DEFAULT_PROBE_INTERVAL_MS, firewall=None, scenarios=(),
                  lines=(), routes=(), monitors=(), devices=(),
                  tls_port=model.DEFAULT_TLS_PORT, tls_cert=None, tls_key=None, tls_ca=None,
                  tls_require_role=True, tls_crl=None, authip=(), bind=None, gateway_unit=0,
                  udp_port=0, rtu_port=0, **table_settings) -> model.MasterConfig:
    serial = serial_config(device, protocol, baudrate, line_format, interface, rtsdelays,
                            stout, silence, ascii_timeout, nocheck, dtr, rts, cts, xonxoff,
                            interframe_silence)
    upstream_tls = upstream_tls_config(table_settings)
    table = table_config(**table_settings)
    tls = tls_config(tls_port, tls_cert, tls_key, tls_ca, tls_require_role, tls_crl)
    conflict = model.table_address_conflict(table.address, slaveid) if table.enabled else None
    if conflict:
        raise click.BadParameter(conflict, param_hint="'--table-address' / '--slaveid'")
    cfg = convert(None, lambda: model.MasterConfig(
        serial=serial, slaveid=slaveid, tcpto_ms=tcpto, mdbport=mdbport, exception=exception,
        upstream_tls=upstream_tls,
        max_connections=max_connections, control=control, metrics=metrics,
        demotion=demotion(down_after, probe_interval), table=table,
        firewall=firewall, scenarios=scenarios, tls=tls, authip=authip, bind=bind,
        udp_port=udp_port, rtu_port=rtu_port, gateway_unit=gateway_unit))
    cfg = with_lines(cfg, "master", lines, routes, monitors, devices)
    if not any(r.face == TCP_FACE for r in cfg.routes):
        for name, port in (("udp-port", udp_port), ("rtu-port", rtu_port)):
            if port:
                raise click.BadParameter("master mode listens there only with a Modbus TCP "
                                         "face: a [[route]] without from",
                                         param_hint=f"'--{name}'")
    return cfg

master.make_config = master_config
