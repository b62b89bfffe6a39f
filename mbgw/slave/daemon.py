"""Runs slave mode: opens the line, listens, tells systemd it is ready, stops on a signal."""
import asyncio
import logging
import signal
import time

from mbgw.config.lines import PRIMARY_LINE
from mbgw.config.model import SlaveConfig
from mbgw.errors import ListenError
from mbgw.line.port import SerialLine
from mbgw.line.supervisor import open_at_start
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceTable, HealthRule
from mbgw.ops.load import LineLoad
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
from mbgw.routing.inbox import Inbox
from mbgw.scenarios.control import scenario_commands
from mbgw.scenarios.engine import Scenarios
from mbgw.scenarios.tcp_runner import TcpScenarios, with_scenarios
from mbgw.slave.line_thread import LineWorker, serial_scenarios
from mbgw.slave.routes import effective_routes
from mbgw.slave.scheduler import Scheduler
from mbgw.slave.server import TcpServer
from mbgw.slave.servers import ServerTargets, server_targets
from mbgw.slave.status import SlaveStatus
from mbgw.slave.table_service import TableService
from mbgw.slave.targets import EveryLine, TargetLines
from mbgw.web.console import start_console
from mbgw.web.hooks import WebHooks

log = logging.getLogger("mbgw")


def run_slave(cfg: SlaveConfig, reconfigure=None, faces=None) -> None:
    """Raises SerialError when the device is there and cannot be opened (one that is not there
    yet is waited for), ListenError when mdbport cannot be bound; otherwise returns after
    SIGTERM or SIGINT.  reconfigure() gives the settings to apply on SIGHUP (None: there is no
    file to reload).  faces(cfg, routes, inboxes, table): the serial faces' threads, unstarted
    (mbgw.gateway's, when some line is in master mode)."""
    counters = Counters()
    line = open_at_start(cfg.serial, counters)
    try:
        asyncio.run(_serve(cfg, line, counters, reconfigure, faces))
    finally:
        if line is not None:
            line.close()


def _servers(cfg: SlaveConfig, inboxes: dict[str, Inbox]) -> ServerTargets | None:
    """The remote servers' thread, unstarted, its inboxes added to inboxes; None: no route
    reaches a server."""
    servers = server_targets(cfg)
    if not servers:
        return None
    thread = ServerTargets(servers, cfg.tcpto_ms, cfg.exception)
    inboxes.update(thread.inboxes)
    return thread


async def _serve(cfg: SlaveConfig, line: SerialLine | None, counters: Counters,  # noqa: C901
                 reconfigure, faces) -> None:
    loop = asyncio.get_running_loop()
    devices = DeviceTable(rule=HealthRule(cfg.demotion))
    scheduler = Scheduler()
    tables = TableService(cfg, devices)
    inboxes: dict[str, Inbox] = {}     # every target's but the table's, by name
    targets = TargetLines(cfg, inboxes)
    servers = _servers(cfg, inboxes)

    worker: LineWorker
    server = TcpServer(cfg, scheduler, counters, lambda: worker.up, devices, tables.table,
                       inboxes)
    server.trace = targets.hub         # one hub: every line's events, named by line
    worker = LineWorker(cfg, line, scheduler, server, counters, devices)
    if cfg.lines:                      # a serial face may reach line serial too
        inboxes[PRIMARY_LINE] = Inbox()
        worker.use_inbox(inboxes[PRIMARY_LINE])
    serial_faces = faces(cfg, effective_routes(cfg), inboxes, tables.table, targets.hub) \
        if faces is not None else []
    serial_engine = Scenarios(serial_scenarios(cfg), tables.table, "serial")
    worker.use_scenarios(serial_engine)      # run, and reconfigured, by the line thread
    engines: dict = {"serial": serial_engine}   # the scenarios' engines by kind
    stop = asyncio.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop.set)
    try:
        addresses = await server.start()
    except ListenError:             # the TLS port's, named already
        raise
    except OSError as err:
        raise ListenError("mdbport", cfg.mdbport, err) from None
    started = time.time()
    load = LineLoad(lambda: counters.line_busy_ns)
    try:
        metrics = start_metrics(cfg.metrics, lambda m: with_scenarios(m.slave_collector(
            counters, devices, scheduler, server, worker, started, tables.figures, load,
            lambda: server.firewall.report() if server.firewall.configured else None,
            lambda: [(PRIMARY_LINE, counters, devices), *targets.metered(),
                     *((face.face, face.counters, face.devices) for face in serial_faces)]),
            engines))
    except ListenError:
        server.close()
        raise
    worker.idle_ms = idle_ms(watchdog_interval())
    worker.start()
    targets.start(worker.idle_ms)
    if servers is not None:
        servers.start()
    for face in serial_faces:
        face.start()
    status = SlaveStatus(cfg, server, worker, scheduler, counters, devices, addresses, tables,
                         load)
    status.targets = targets
    status.faces = serial_faces
    status.scenario_engines = engines
    commands = {**status.commands(), **scenario_commands(engines, cfg.config_file)}
    control = await start_control(cfg.control, commands)
    reloads = Reloads(status, reconfigure)
    console = await start_console(cfg.web, WebHooks(commands, status.trace_hub,
                                                    cfg.config_file, reloads.run))
    s = cfg.serial
    log.info("slave mode: listening on %s; serial %s %d %s %s %s, stout %d ms%s%s",
             ", ".join(addresses), s.device, s.baudrate, s.format, s.protocol, s.wiring,
             s.stout_ms, ", nocheck" if s.nocheck else "", origin(cfg))
    warn_of_overlaps(cfg)
    if metrics is not None:
        log.info("metrics on %s", ", ".join(f"http://{a}/metrics" for a in metrics.names))
    if s.nocheck:
        log.warning("nocheck is on: serial replies are forwarded unchecked (a debugging mode)")

    scenarios = TcpScenarios(tables.table, engines, devices.rule, server.trace)
    scenarios.start(cfg.scenarios, cfg.tcpto_ms, cfg.upstream_tls)

    running = cfg                      # the settings in force

    async def apply(new: SlaveConfig, report: ReloadReport) -> None:
        nonlocal servers, running
        await console.reconfigure(new.web, report)
        tables.reconfigure(new, report)
        removed = await asyncio.to_thread(targets.reconfigure, new, report)
        old_servers = servers
        if (new.tcpto_ms, new.exception, server_targets(new)) != \
                (running.tcpto_ms, running.exception, server_targets(running)):
            for label in server_targets(running):
                inboxes.pop(label, None)
            servers = _servers(new, inboxes)
            if servers is not None:
                servers.start()
        else:
            old_servers = None
        await server.reconfigure(new, report)
        worker.configured.clear()
        worker.reconfigure(new)        # the face routes to the targets in force from then on
        await asyncio.to_thread(worker.configured.wait, worker.turn_limit_s + 1)
        for target in removed:
            target.stop()
            await asyncio.to_thread(target.join)
        if old_servers is not None:
            old_servers.stop()
            await asyncio.to_thread(old_servers.join_and_close)
        await asyncio.to_thread(scenarios.reconfigure, new.scenarios, new.tcpto_ms,
                                new.upstream_tls)
        running = new
    reloads.apply = apply

    kept = asyncio.ensure_future(tables.keep())
    sampled = asyncio.ensure_future(load.keep())
    try:
        await serve_until_stopped(stop, status, EveryLine(worker, targets), reloads, control,
                                  metrics)
    finally:
        await console.close()
        await asyncio.to_thread(scenarios.stop)
    kept.cancel()
    sampled.cancel()
    server.close()
    for face in serial_faces:
        face.stop()
    for face in serial_faces:
        await asyncio.to_thread(face.join)
    targets.stop()
    worker.stop()
    await asyncio.to_thread(worker.join)
    await asyncio.to_thread(targets.join)
    if servers is not None:
        servers.stop()
        await asyncio.to_thread(servers.join_and_close)
    tables.save()
    serial_engine.close()
    scheduler.close()
    log_stopped(counters)

