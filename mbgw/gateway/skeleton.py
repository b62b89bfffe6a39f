"""The daemon's skeleton, written once for every mode: a mode builds its own objects
(mbgw.ops.service.ModeParts) and serve_mode runs them with what every daemon has: the signals,
the metrics endpoint, the watchdog over every line thread, the control socket, the web console,
the TCP scenarios, the reload and the stop.  It lives here, not in ops, because it starts the
scenarios and the console, which ops may not import."""
import asyncio
import logging
import signal
import time

from mbgw.errors import ListenError
from mbgw.gateway.northbound import NorthboundService
from mbgw.ops.events import EventRing
from mbgw.ops.reload import ReloadReport, Reloads
from mbgw.ops.restart import Restart
from mbgw.ops.service import (
    EveryThread,
    ModeParts,
    idle_ms,
    log_stopped,
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


async def serve_mode(parts: ModeParts, reconfigure, restart: Restart | None = None) -> None:
    """Runs the mode's parts until SIGTERM or SIGINT, then stops them.  reconfigure() gives the
    settings a reload applies (None: there is no file).  Raises ListenError when the metrics
    address cannot be listened on (the parts abandoned)."""
    cfg = parts.cfg
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop.set)
    started = time.time()
    engines = parts.engines            # the scenarios' engines by kind; "tcp" while they run
    parts.status.scenario_engines = engines
    northbound = NorthboundService(parts, engines)
    try:
        metrics = start_metrics(cfg.metrics, lambda m: northbound.with_metrics(_with_lines(
            with_scenarios(parts.collector(m, started), engines), parts)))
    except ListenError:
        parts.abandon()
        raise
    parts.start(idle_ms(watchdog_interval()))
    commands = northbound.with_status({**parts.status.commands(), **parts.commands,
                                       **scenario_commands(engines, cfg.config_file)})
    control = await start_control(cfg.control, commands)
    reloads = Reloads(parts.status, reconfigure)
    events = EventRing().attach()
    restart = restart or Restart()
    restart.stop = stop
    console = await start_console(cfg.web, WebHooks(commands, parts.status.trace_hub,
                                                    cfg.config_file, reloads.run,
                                                    events, restart))
    parts.log_start()
    warn_of_overlaps(cfg)
    if metrics is not None:
        log.info("metrics on %s", ", ".join(f"http://{a}/metrics" for a in metrics.names))

    def client_tls(settings):
        return settings.upstream_tls if parts.client_tls else None

    scenarios = TcpScenarios(parts.table, engines, parts.health, parts.trace)
    scenarios.start(cfg.scenarios, cfg.tcpto_ms, client_tls(cfg))
    northbound.start(cfg)

    async def apply(new, report: ReloadReport) -> None:
        await console.reconfigure(new.web, report)
        await parts.apply(new, report)
        await asyncio.to_thread(scenarios.reconfigure, new.scenarios, new.tcpto_ms,
                                client_tls(new))
        await northbound.reconfigure(new)
    reloads.apply = apply

    tasks = [asyncio.ensure_future(task()) for task in parts.tasks()]
    try:
        await serve_until_stopped(stop, parts.status, EveryThread(parts.threads), reloads,
                                  control, metrics)
    finally:
        await northbound.stop()
        await console.close()
        await asyncio.to_thread(scenarios.stop)
    for task in tasks:
        task.cancel()
    await parts.stop()
    log_stopped(parts.counters)
    events.detach()


def _with_lines(collector, parts: ModeParts):
    """The daemon's metrics collector with every line's families."""
    collector.lines = parts.lines
    return collector
