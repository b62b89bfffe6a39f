"""Runs master mode: opens the line, serves the serial master, tells systemd it is ready,
stops on a signal; the operator's tools (control socket, metrics, SIGHUP reload, systemd's
watchdog) are mbgw.ops.service's."""
import asyncio
import logging
import signal
import time

from mbgw.config.lines import PRIMARY_LINE
from mbgw.config.model import MasterConfig
from mbgw.master.faces import Faces
from mbgw.master.status import MasterStatus
from mbgw.master.table_service import TableService
from mbgw.ops.counters import MasterCounters
from mbgw.ops.reload import ReloadReport, Reloads
from mbgw.ops.service import (
    idle_ms,
    log_stopped,
    origin,
    serve_until_stopped,
    start_control,
    start_metrics,
    warn_of_overlaps,
    watchdog_interval,
)
from mbgw.scenarios.control import scenario_commands
from mbgw.scenarios.tcp_runner import TcpScenarios, with_scenarios
from mbgw.web.console import start_console
from mbgw.web.hooks import WebHooks

log = logging.getLogger("mbgw")
TICK_S = 1.0        # how often the table's file is looked at (it is saved per its interval)


def run_master(cfg: MasterConfig, reconfigure=None) -> None:
    """Raises SerialError when the device is there and cannot be opened (one that is not
    there yet is waited for), ListenError when the metrics address, table-port or
    tls-port cannot be listened on; otherwise
    returns after SIGTERM or SIGINT.  reconfigure() gives the settings to apply on SIGHUP
    (None: there is no file to reload)."""
    counters = MasterCounters()
    tables = TableService(cfg)
    faces = Faces.opened(cfg, counters, tables.table)
    try:
        tables.start()
        asyncio.run(_serve(cfg, faces, counters, tables, reconfigure))
    finally:
        tables.stop()
        faces.close()


def table_address(cfg: MasterConfig) -> int:
    """The serial address the table answers as; 0: none."""
    return cfg.table.address if cfg.table.enabled else 0


async def _tick(tables: TableService) -> None:
    while True:
        await asyncio.sleep(TICK_S)
        await asyncio.to_thread(tables.tick)       # a save writes and fsyncs a file


def _log_slaveid(cfg: MasterConfig) -> None:
    if cfg.slaveid.ranges or any(r.face == PRIMARY_LINE for r in cfg.routes):
        return
    if table_address(cfg):
        log.info("the slaveid table is empty: mbgw is a Modbus %s server of the exchange "
                 "table only, at address %d", cfg.serial.protocol.upper(), cfg.table.address)
    else:
        log.warning("the slaveid table is empty: every request on the line is ignored")


async def _serve(cfg: MasterConfig, faces: Faces, counters: MasterCounters,
                 tables: TableService, reconfigure) -> None:
    slave = faces.primary
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop.set)
    started = time.time()
    engines: dict = {}         # the scenarios' engine by kind, while it runs (TCP only here)
    metrics = start_metrics(cfg.metrics, lambda m: with_scenarios(m.master_collector(
        counters, slave.devices, slave, started,
        lambda: tables.figures(slave.table_counters.snapshot()), tables.firewall_report,
        faces.metered), engines))
    faces.start(idle_ms(watchdog_interval()))
    status = MasterStatus(cfg, slave, counters, tables)
    status.scenario_engines = engines
    status.other_faces = faces.others
    commands = {**status.commands(), **scenario_commands(engines, cfg.config_file)}
    control = await start_control(cfg.control, commands)
    reloads = Reloads(status, reconfigure)
    console = await start_console(cfg.web, WebHooks(commands, status.trace_hub,
                                                    cfg.config_file, reloads.run))
    s = cfg.serial
    log.info("master mode: serial %s %d %s %s %s; servers' port %d, tcpto %d ms, exception %s, "
             "at most %d connections; slaveid %s%s", s.device, s.baudrate, s.format, s.protocol,
             s.wiring, cfg.mdbport, cfg.tcpto_ms, "on" if cfg.exception else "off",
             cfg.max_connections, cfg.slaveid, origin(cfg))
    warn_of_overlaps(cfg)
    if metrics is not None:
        log.info("metrics on %s", ", ".join(f"http://{a}/metrics" for a in metrics.names))
    _log_slaveid(cfg)
    scenarios = TcpScenarios(tables.table, engines, slave.devices.rule, slave.hub)
    scenarios.start(cfg.scenarios, cfg.tcpto_ms, cfg.upstream_tls)

    async def apply(new: MasterConfig, report: ReloadReport) -> None:
        await console.reconfigure(new.web, report)
        _log_slaveid(new)
        tables.reconfigure(new, report)
        faces.reconfigure(new)
        await asyncio.to_thread(scenarios.reconfigure, new.scenarios, new.tcpto_ms,
                                new.upstream_tls)
    reloads.apply = apply

    ticking = asyncio.ensure_future(_tick(tables))
    try:
        await serve_until_stopped(stop, status, slave, reloads, control, metrics)
    finally:
        await console.close()
        await asyncio.to_thread(scenarios.stop)
    ticking.cancel()
    faces.stop()
    await asyncio.to_thread(faces.join)
    log_stopped(counters)
