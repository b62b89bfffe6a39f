"""What every mode's daemon shares: what a mode hands the daemon's skeleton (ModeParts, run by
mbgw.gateway.skeleton.serve_mode), systemd notification and its watchdog over every line
thread, the control socket and metrics endpoint started and closed, the stop and its last log
line (the SIGHUP reload is mbgw.ops.reload's)."""
import asyncio
import logging
import math
import os
import time
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from mbgw import errors
from mbgw.ops.control import ControlServer, default_path
from mbgw.ops.notify import sd_notify
from mbgw.ops.reload import Reloads

if TYPE_CHECKING:
    from mbgw.ops.metrics_server import MetricsServer

log = logging.getLogger("mbgw")

STATUS_PERIOD_S = 5.0    # how often systemd's STATUS= line is brought up to date


class ModeParts:
    """What a mode's daemon hands the skeleton (mbgw.gateway.skeleton.serve_mode), which does
    the rest the same for every mode: signals, metrics, the watchdog, the control socket, the
    console, the TCP scenarios, reload, stop.  A mode subclasses it with its own objects and
    fills in what differs; the attributes are what the skeleton reads."""
    table: Any = None         # the exchange table the TCP scenarios use
    health: Any = None        # the demotion rule the TCP scenarios follow (HealthRule)
    trace: Any = None         # the trace hub the TCP scenarios' transactions go to
    client_tls = True         # the TCP scenarios use [upstream-tls] (a mode without it: off)

    def __init__(self, cfg, status, counters) -> None:
        self.cfg = cfg                 # the settings it starts with
        self.status = status           # its mbgw.ops.status.DaemonStatus
        self.counters = counters       # what the last log line shows (snapshot())
        self.commands: dict = {}       # control commands beside the status's
        self.engines: dict = {}        # its scenarios' engines by kind; the skeleton adds tcp

    def threads(self) -> list:
        """Every line thread now (the watchdog's: a reload adds and removes lines)."""
        raise NotImplementedError

    def start(self, idle_ms: int) -> None:
        """Starts the mode's threads, given the longest a line thread may wait idle."""
        raise NotImplementedError

    def collector(self, metrics, started: float):
        """The mode's metrics collector, from the module mbgw.ops.metrics."""
        raise NotImplementedError

    def log_start(self) -> None:
        """The mode's start-up lines."""

    def lines(self) -> list[dict]:
        """Every line's status row (name, device, mode, state, requests, replies, timeouts),
        for the metrics; none in a mode of one line only."""
        return []

    async def apply(self, new, report) -> None:
        """A reload's new settings for the mode's own objects (ReloadReport report)."""

    async def stop(self) -> None:
        """Stops, joins and closes the mode's objects."""

    def abandon(self) -> None:
        """The start failed after the parts were built: what they opened is closed."""

    def tasks(self) -> tuple[Callable[[], Awaitable[None]], ...]:
        """Loop tasks while it runs (cancelled at the stop)."""
        return ()


class EveryThread:
    """The daemon's line threads as one for systemd's watchdog: it turns while each of them
    does (the oldest heartbeat, the longest turn).  threads() is asked each time: a reload
    adds and removes lines."""

    def __init__(self, threads: Callable[[], list]) -> None:
        self._threads = threads

    @property
    def heartbeat(self) -> float:
        return min(t.heartbeat for t in self._threads())

    @property
    def turn_limit_s(self) -> float:
        return max(t.turn_limit_s for t in self._threads())

    def is_alive(self) -> bool:
        return all(t.is_alive() for t in self._threads())


def watchdog_interval() -> float | None:
    """Half of systemd's WatchdogSec= (WATCHDOG_USEC) when its watchdog is on for this
    process (WATCHDOG_PID, when set, is ours); None when it is off."""
    pid = os.environ.get("WATCHDOG_PID")
    if pid and pid != str(os.getpid()):
        return None
    try:
        usec = int(os.environ.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    return usec / 2_000_000 if usec > 0 else None


def idle_ms(interval: float | None) -> int:
    """The longest a line thread may wait while nothing happens (-1: no limit): it must turn
    at least once per watchdog interval."""
    return -1 if interval is None else math.ceil(interval * 1000)


def start_metrics(address: str | None, collector) -> "MetricsServer | None":
    """The --metrics endpoint (None when off) serving collector(mbgw.ops.metrics); .names are
    its listening addresses.  Raises ListenError when it cannot listen.  Without
    --metrics, mbgw.ops.metrics(_server) and prometheus_client are never imported (45 ms,
    3 MiB)."""
    if not address:
        return None
    from mbgw.ops import metrics as module
    from mbgw.ops.metrics_server import MetricsServer
    metrics = MetricsServer(address, collector(module))
    try:
        metrics.names = metrics.start()
    except OSError as err:
        raise errors.ListenError("--metrics", address, err) from None
    return metrics


async def start_control(path: str | None, commands: dict) -> ControlServer | None:
    """The control socket; None (logged) when it cannot be had: the gateway runs without."""
    control = ControlServer(path or default_path(), commands)
    try:
        await control.start()
    except OSError as err:
        log.warning("control socket %s unavailable (%s): mbgw status and trace will not "
                    "reach this daemon", control.path, err.strerror)
        return None
    return control


async def serve_until_stopped(stop: asyncio.Event, holder, line, reloads: Reloads,
                              control: ControlServer | None,
                              metrics: "MetricsServer | None") -> None:
    """Ready: reload on SIGHUP (mbgw.ops.reload), tell systemd, keep it told (see
    tell_systemd), wait for `stop` (SIGTERM, SIGINT), then tell systemd and close the
    operator's tools; the mode closes its own objects after."""
    reloads.on_sighup(asyncio.get_running_loop())
    sd_notify("READY=1")
    told = asyncio.ensure_future(tell_systemd(line, holder.summary, watchdog_interval())) \
        if os.environ.get("NOTIFY_SOCKET") else None
    await stop.wait()
    if told is not None:
        told.cancel()
    sd_notify("STOPPING=1")
    log.info("stopping")
    close_tools(control, metrics)


async def tell_systemd(line, summary, interval: float | None) -> None:
    """WATCHDOG=1 every interval (None: no watchdog) while the line thread turns: its
    heartbeat is no older than the longest a turn takes while all is well (turn_limit_s)
    plus the interval, the longest it waits idle; and STATUS=summary() when it changes.
    A line thread that stops turning is logged, once: systemd restarts the daemon when
    WatchdogSec= passes without a ping."""
    period = min(interval or STATUS_PERIOD_S, STATUS_PERIOD_S)
    shown, stuck = None, False
    while True:
        if interval is not None:
            age = time.monotonic() - line.heartbeat
            turning = line.is_alive() and age <= line.turn_limit_s + interval
            if turning:
                sd_notify("WATCHDOG=1", wait=False)
            if turning == stuck:
                stuck = not turning
                _log_line_thread(stuck, age, line)
        text = f"{summary()}; line thread stuck" if stuck else summary()
        if text != shown and sd_notify(f"STATUS={text}", wait=False):
            shown = text
        await asyncio.sleep(period)


def _log_line_thread(stuck: bool, age: float, line) -> None:
    if not stuck:
        log.warning("the line thread turns again: watchdog pings resumed")
    elif not line.is_alive():
        log.error("the line thread has ended: no more watchdog pings, systemd restarts mbgw")
    else:
        log.error("the line thread has not turned for %.1f s (a turn takes at most %.1f s): "
                  "no more watchdog pings, systemd restarts mbgw", age, line.turn_limit_s)


def close_tools(control: ControlServer | None, metrics: "MetricsServer | None") -> None:
    if control is not None:
        control.close()
    if metrics is not None:
        metrics.close()


def origin(cfg) -> str:
    """The start-up line's end: the file the settings came from, the table, the scenarios."""
    names = [sc.name for sc in getattr(cfg, "scenarios", ())]
    table = "" if getattr(cfg, "transparent", None) is not None else \
        "; table on" if cfg.table.enabled else \
        "; table on (scenarios)" if cfg.table_on else "; table off"
    return (f"; configuration {cfg.config_file or 'none (command line)'}{table}; "
            f"scenarios {', '.join(names) if names else 'none'}")


def warn_of_overlaps(cfg) -> None:
    """Two read scenarios storing into the same table registers: logged at start, as
    check-config warns of it."""
    from mbgw.config.scenario import overlaps
    for warning in overlaps(getattr(cfg, "scenarios", ())):
        log.warning("%s", warning)


def log_stopped(counters) -> None:
    log.info("stopped; counters: %s",
             " ".join(f"{k}={v}" for k, v in counters.snapshot().items()))


def remonitor(monitors, make, cfg, table, hub, idle_ms: int, report):
    """The monitor lines after a reload to cfg (blocking: a worker thread's call): monitors
    (monitor.lines.MonitorLines; None: none ran) reconfigured, or, for the first ones, made by
    make(cfg, table, hub) (the daemon's factory, mbgw.gateway's; None: none run here) and
    started.  Returns them (None: none)."""
    if monitors is not None:
        monitors.reconfigure(cfg, report)
        return monitors
    if make is None:
        return None
    try:
        made = make(cfg, table, hub)
    except errors.SerialError as err:     # a device there that does not open
        log.error("monitor lines not opened: %s", err.strerror or err)
        report.refuse("lines", f"monitor lines: {err.strerror or err}")
        return None
    if made is not None:
        made.start(idle_ms)
    return made
