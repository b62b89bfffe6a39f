"""The lines in slave mode beside `serial` (`[[line]]`, mode slave): targets, each a SlaveLineThread
of its own (its SerialLine, Scheduler, SerialMaster, DeviceHealth, Counters; one thread) with
no TCP connection of its own.  Requests reach it as Exchanges through its Inbox, from the Modbus
TCP face (mbgw.slave.server) or a serial face; each becomes a job in its source's queue, under
the same rules as line serial's (line down, demotion, retries, late windows), and the face is
told the outcome on this line's thread (Exchange.done).
"""
import dataclasses
import logging

from mbgw.config.lines import LineConfig, line_devices
from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.errors import SerialError
from mbgw.line.serial_line import SerialLine
from mbgw.line.supervisor import open_at_start
from mbgw.ops.counters import Counters, RemoteCounters
from mbgw.ops.device_stats import DeviceHealth, HealthRule
from mbgw.ops.reload import ReloadReport
from mbgw.ops.status import line_row, settings_row
from mbgw.ops.trace import LineTrace, TraceHub
from mbgw.routing.cache import ReadCache
from mbgw.routing.queue import Inbox, Scheduler
from mbgw.slave.connections import Connections
from mbgw.slave.line_thread import SlaveLineThread
from mbgw.slave.remote_line import RemoteLineThread

log = logging.getLogger("mbgw.line")


def line_settings(cfg: SlaveConfig | MasterConfig, line: LineConfig) -> SlaveConfig:
    """The daemon's settings as a target line's worker reads them: the line's port, retries
    and demotion; no table, no scenarios, no shortcut (no client of its own).  In a
    master-mode daemon (cfg a MasterConfig) the line's own timing and the daemon's
    `exception` make the rest."""
    base = cfg if isinstance(cfg, SlaveConfig) else SlaveConfig(
        serial=line.serial, exception=cfg.exception, turnaround_ms=line.turnaround_ms,
        late_window_ms=line.late_window_ms)
    settings = dataclasses.replace(
        base, serial=line.serial, retries=line.retries, demotion=line.demotion, slaveid=0,
        cache=line.cache,
        shortcut=False, scenarios=(), table=dataclasses.replace(cfg.table, enabled=False),
        lines=(), routes=(), monitors=(), devices=line_devices(cfg.devices, line.name))
    if line.remote is not None and line.remote.mbap:
        # our own transaction ids tell a late reply from the next one's: no late window
        settings = dataclasses.replace(settings, late_window_ms=0)
    return settings


def route_caches_to(cfg: SlaveConfig | MasterConfig, line: LineConfig) -> list:
    """The cache rules of the routes to line: a reload that changes one empties its cache."""
    return [r.cache for r in cfg.routes if r.line == line.name]


class NoClients:
    """What a target line's worker has where line serial's has the TcpServer: a Connections
    with no client (its poll: the wake-up eventfd, the inbox, the serial port)."""
    table = None
    reads_meanwhile = False
    shortcut_allowed = False

    def __init__(self, scheduler: Scheduler, counters: Counters, trace: LineTrace) -> None:
        self.trace = trace
        self.cache = ReadCache()
        self.connections = Connections(scheduler.wake_fd, self._no_client, self._no_client,
                                       counters)

    def route_face(self, cfg: SlaveConfig) -> None:
        """No face here."""

    @staticmethod
    def _no_client(*_) -> None:
        raise AssertionError("a target line has no client of its own")

    finished = _no_client
    traced_late = _no_client


class TargetLine:
    """One target line: its worker, its inbox and what it keeps per line."""

    def __init__(self, cfg: SlaveConfig | MasterConfig, line: LineConfig,
                 hub: TraceHub | None = None) -> None:
        """hub: the daemon's trace hub (None: one of its own, nobody subscribes)."""
        self.config = line
        self.own = line_devices(cfg.devices, line.name)     # its [[device]] tables
        hub = hub if hub is not None else TraceHub()
        self.counters = RemoteCounters() if line.remote is not None else Counters()
        self.devices = DeviceHealth(rule=HealthRule(line.demotion))
        self.scheduler = Scheduler()
        self.inbox = Inbox()
        settings = line_settings(cfg, line)
        clients = NoClients(self.scheduler, self.counters, hub.for_line(line.name))
        self.worker: SlaveLineThread
        if isinstance(self.counters, RemoteCounters):
            self.worker = RemoteLineThread(settings, line, self.scheduler, clients,
                                           self.counters, self.devices)
        else:
            port: SerialLine | None = open_at_start(line.serial, self.counters)
            self.worker = SlaveLineThread(settings, port, self.scheduler, clients,
                                          self.counters, self.devices)
        self.worker.name_line(line.name)
        self.worker.use_inbox(self.inbox)
        self._route_caches = route_caches_to(cfg, line)

    def start(self) -> None:
        self.worker.start()

    def stop(self) -> None:
        self.worker.stop()

    def join(self) -> None:
        """After stop(); then its port is closed (the worker closes it) and its fds."""
        self.worker.join()
        self.scheduler.close()
        self.inbox.close()

    def reconfigure(self, cfg: SlaveConfig | MasterConfig, line: LineConfig) -> None:
        self.config = line
        self.own = line_devices(cfg.devices, line.name)
        if isinstance(self.worker, RemoteLineThread):
            self.worker.set_target(line)
        caches = route_caches_to(cfg, line)
        if caches != self._route_caches:
            self._route_caches = caches
            self.worker.empty_cache = True
        self.worker.reconfigure(line_settings(cfg, line))

    def status(self) -> dict:
        c = self.counters
        s = self.config.serial
        return {"name": self.config.name, "device": s.device, "mode": self.config.mode,
                "state": self.worker.state, "requests": c.requests, "replies": c.replies,
                "timeouts": c.timeouts}

    def row(self) -> dict:
        """status() with all its counters and its devices (mbgw status's row)."""
        counters = self.counters.snapshot()
        return line_row(self.config.name, self.config.serial.device, self.config.mode,
                        self.worker.state, counters, [d.snapshot() for d in self.devices.all()],
                        self.worker.cache.reads.status(), settings_row(self.config),
                        self.worker.state_since)


class TargetLines:
    """Every target line but serial, by name: opened at start, added, changed and removed by
    a reload.  inboxes is the dict the TCP face routes with (line serial's included when a
    serial face may reach it)."""

    def __init__(self, cfg: SlaveConfig | MasterConfig, inboxes: dict[str, Inbox],
                 hub: TraceHub | None = None) -> None:
        """hub: the daemon's trace hub (None: one of their own, nobody subscribes)."""
        self.inboxes = inboxes
        self.hub = hub if hub is not None else TraceHub()
        self.lines: dict[str, TargetLine] = {}
        self._idle_ms = -1                 # the watchdog's idle limit, for lines added later
        for line in target_lines(cfg):
            self._add(cfg, line)

    def _add(self, cfg: SlaveConfig | MasterConfig, line: LineConfig) -> TargetLine:
        target = self.lines[line.name] = TargetLine(cfg, line, self.hub)
        self.inboxes[line.name] = target.inbox
        return target

    def start(self, idle_ms: int = -1) -> None:
        self._idle_ms = idle_ms
        for target in self.lines.values():
            target.worker.idle_ms = idle_ms
            target.start()

    def stop(self) -> None:
        for target in self.lines.values():
            target.stop()

    def join(self) -> None:
        for target in self.lines.values():
            target.join()

    def reconfigure(self, cfg: SlaveConfig | MasterConfig,
                    report: ReloadReport | None = None) -> list[TargetLine]:
        """Lines added are opened and started, changed ones reconfigured (reopened when their
        port settings changed), the others kept as they are; an added line whose device is
        there and does not open is told to the report (its units are unrouted).  Returns the
        removed ones, out of the inboxes already: the caller stops and joins them once the
        face no longer routes to them."""
        wanted = {line.name: line for line in target_lines(cfg)}
        removed = [self.lines.pop(name) for name in list(self.lines) if name not in wanted]
        for target in removed:
            self.inboxes.pop(target.config.name, None)
        for name, line in wanted.items():
            kept = self.lines.get(name)
            if kept is None:
                try:
                    added = self._add(cfg, line)
                    added.worker.idle_ms = self._idle_ms
                    added.start()
                except SerialError as err:    # a device there that does not open
                    log.error("line %s not opened: %s", name, err.strerror or err)
                    if report is not None:
                        report.refuse("lines", f"line {name}: {err.strerror or err}")
                    self.lines.pop(name, None)
                    self.inboxes.pop(name, None)
            elif kept.config != line or kept.own != line_devices(cfg.devices, name):
                kept.reconfigure(cfg, line)
        return removed

    def metered(self) -> list[tuple]:
        """Each line's (name, counters, devices) for /metrics."""
        return [(name, t.counters, t.devices) for name, t in list(self.lines.items())]

    def status(self) -> list[dict]:
        return [t.row() for t in list(self.lines.values())]   # a reload may be adding

    def threads(self) -> list[SlaveLineThread]:
        """Their threads, for the watchdog."""
        return [t.worker for t in list(self.lines.values())]


def target_lines(cfg: SlaveConfig | MasterConfig) -> list[LineConfig]:
    return [line for line in cfg.lines if line.is_target and line.name != "serial"]
