"""Runs transparent mode: opens the line, serves the table on mdbport (mbgw.table.server)
and the raw port, runs the line thread (mbgw.transparent.line_thread), tells systemd it is
ready, stops on a signal; the skeleton that runs them (signals, control socket, metrics,
reload, systemd's watchdog) is mbgw.gateway.skeleton's."""
import asyncio
import logging

from mbgw.config.transparent import TransparentModeConfig
from mbgw.errors import ConfigError, ListenError
from mbgw.firewall.guard import Firewall
from mbgw.line.supervisor import open_at_start
from mbgw.net.acl import AccessList
from mbgw.net.listen import listen
from mbgw.net.tls import server_context
from mbgw.ops.reload import ReloadReport
from mbgw.ops.service import ModeParts, origin
from mbgw.table import identity
from mbgw.table.control import table_commands
from mbgw.table.memory import Table
from mbgw.table.report import table_status
from mbgw.table.server import TableServer
from mbgw.transparent.counters import TransparentCounters
from mbgw.transparent.line_thread import TransparentLineThread
from mbgw.transparent.raw import RawPort
from mbgw.transparent.status import TransparentStatus

log = logging.getLogger("mbgw")


def _raw_port(cfg: TransparentModeConfig, allows, counters) -> RawPort | None:
    port = cfg.transparent.raw_port
    if port is None:
        return None
    return RawPort(listen(cfg.bind, port, option="raw-port"), allows, counters)


def run_transparent(cfg: TransparentModeConfig, reconfigure, serve) -> None:
    """Raises SerialError when the device is there and cannot be opened (one that is not
    there yet is waited for), ListenError when mdbport,
    raw-port or the metrics address cannot be listened on; otherwise returns after SIGTERM or
    SIGINT.  reconfigure() gives the settings SIGHUP applies (None: no file).
    serve(parts, reconfigure): the daemon's skeleton (mbgw.gateway.skeleton.serve_mode)."""
    counters = TransparentCounters()
    table = Table(cfg.table.functions)
    identity.fill(table, cfg, "transparent")
    allows = AccessList(cfg.authip).allows
    context = server_context(cfg.tls) if cfg.tls.enabled else None     # ConfigError
    server = TableServer(table, cfg.mdbport or None, cfg.bind,
                         Firewall(cfg.firewall, cfg.tls.roles_required),
                         allows=allows, tls=context, tls_port=cfg.tls.port,
                         max_connections=cfg.table.max_connections, port_option="mdbport")
    server.request_timeout_s = cfg.request_timeout_ms / 1000
    raw = _raw_port(cfg, allows, counters)
    line = open_at_start(cfg.serial, counters)
    try:
        frames = TransparentLineThread(cfg, line, table, raw, counters)
    except BaseException:
        if line is not None:
            line.close()
        raise
    server.start()
    try:
        asyncio.run(serve(TransparentMode(cfg, frames, counters, table, server, raw),
                          reconfigure))
    finally:
        server.stop()
        server.join()


def _retls(server: TableServer, new: TransparentModeConfig, report: ReloadReport) -> None:
    """New TLS settings or renewed files, for new connections; those open keep theirs.  Ones
    that cannot be loaded leave TLS as it was."""
    try:
        server.set_tls(server_context(new.tls) if new.tls.enabled else None, new.tls.port)
    except (ConfigError, ListenError) as err:
        report.refuse("tls", f"{err}; the running TLS settings stay")


async def _rebind(server: TableServer, bind: str | None, report: ReloadReport) -> None:
    try:
        await asyncio.to_thread(server.rebind, bind)
    except ListenError as err:
        report.refuse("bind", f"{err.strerror}; still listening on "
                              f"{', '.join(server.addresses) or 'no port'}")


class TransparentMode(ModeParts):
    """Transparent mode's objects: the line thread, the table's server, the raw port.  Its
    TCP scenarios reach their servers without TLS: the mode has no [upstream-tls] settings
    (no client certificate to present)."""
    client_tls = False

    def __init__(self, cfg: TransparentModeConfig, frames: TransparentLineThread, counters,
                 table: Table, server: TableServer, raw: RawPort | None) -> None:
        super().__init__(cfg, TransparentStatus(cfg, frames, counters, self._table_figures,
                                                raw, server), counters)
        self.frames, self.server, self.raw = frames, server, raw
        self.table, self.trace = table, self.status.trace_hub
        self.commands = table_commands(table)

    def _table_figures(self) -> dict:
        return table_status(self.table, self.cfg.table, None, None, self.server.figures())

    def threads(self) -> list:
        return [self.frames]

    def collector(self, metrics, started: float):
        return metrics.transparent_collector(self.frames, self.status.figures, started,
                                             self._table_figures)

    def start(self, idle_ms: int) -> None:
        self.frames.idle_ms = idle_ms
        self.frames.start()

    def log_start(self) -> None:
        cfg, raw = self.cfg, self.raw
        s, t = cfg.serial, cfg.transparent
        log.info("transparent mode: serial %s %d %s %s; eof %s, eof-timeout %d ms, rx %d+%d "
                 "bytes, tx %d+%d bytes, crc %s, trigger %s, silence %d ms; table on %s%s%s",
                 s.device, s.baudrate, s.format, s.wiring, t.eof if t.eof != "char" else
                 f"char 0x{t.eof_char:02x}", t.eof_timeout_for(s), t.rx_address, t.rx_size,
                 t.tx_address, t.tx_size, "on" if t.crc else "off",
                 "on" if t.trigger else "off", t.silence_ms, ", ".join(self.server.addresses),
                 f"; raw port {raw.port}" if raw is not None else "", origin(cfg))

    async def apply(self, new: TransparentModeConfig, report: ReloadReport) -> None:
        old, server, raw = self.status.cfg, self.server, self.raw
        identity.fill(self.table, new, "transparent")
        if new.mdbport != old.mdbport:
            report.at_restart("mdbport")
        if new.authip != old.authip:
            allows = AccessList(new.authip).allows
            server.set_access(allows)
            if raw is not None:
                raw.allows = allows             # for its next client
        if new.bind != old.bind:
            if raw is not None:                 # the raw port's listener stays where it is
                report.at_restart("bind")
            else:
                await _rebind(server, new.bind, report)
        if new.transparent.raw_port != old.transparent.raw_port:
            report.at_restart("transparent.raw_port")
        if (new.firewall, new.tls.roles_required) != (old.firewall, old.tls.roles_required):
            server.set_firewall(server.firewall.renewed(new.firewall, new.tls.roles_required))
        server.request_timeout_s = new.request_timeout_ms / 1000
        server.max_connections = new.table.max_connections
        if new.tls != old.tls:
            _retls(server, new, report)
        self.frames.reconfigure(new)

    async def stop(self) -> None:
        self.frames.stop()
        await asyncio.to_thread(self.frames.join)
