"""Slave mode's daemon: opens line serial, listens (the Modbus TCP face), builds the target
lines, the remote servers and the serial faces; the skeleton that runs them is
mbgw.gateway.skeleton's."""
import asyncio
import dataclasses
import logging
from typing import Any

from mbgw.config.lines import PRIMARY_LINE
from mbgw.config.model import SlaveConfig
from mbgw.config.monitor import monitor_settings
from mbgw.errors import ListenError
from mbgw.line.serial_line import SerialLine
from mbgw.line.supervisor import open_at_start
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth, HealthRule
from mbgw.ops.load import LineLoad
from mbgw.ops.reload import ReloadReport
from mbgw.ops.service import ModeParts, origin, remonitor
from mbgw.routing.queue import Inbox, Scheduler
from mbgw.routing.survey import SurveyLine, survey_commands
from mbgw.scenarios.engine import Scenarios
from mbgw.slave.line_scenarios import serial_scenarios
from mbgw.slave.line_share import LineShare
from mbgw.slave.line_thread import SlaveLineThread
from mbgw.slave.server import TcpServer
from mbgw.slave.servers import ServerTargets, how_reached, server_targets
from mbgw.slave.status import SlaveStatus
from mbgw.slave.table_service import TableService
from mbgw.slave.targets import TargetLines
from mbgw.slave.tcp_face import FaceThread

log = logging.getLogger("mbgw")


def run_slave(cfg: SlaveConfig, reconfigure, serve, faces=None, monitors=None) -> None:
    """Raises SerialError when the device is there and cannot be opened (one that is not there
    yet is waited for), ListenError when mdbport cannot be bound; otherwise returns after
    SIGTERM or SIGINT.  reconfigure() gives the settings to apply on SIGHUP (None: there is no
    file to reload).  serve(parts, reconfigure): the daemon's skeleton
    (mbgw.gateway.skeleton.serve_mode).  faces(cfg, routes, inboxes, table): the serial faces'
    threads, unstarted (mbgw.gateway's, when some line is in master mode).
    monitors(cfg, table, hub): the lines in monitor mode, unstarted, or None."""
    counters = Counters()
    line = open_at_start(cfg.serial, counters) if cfg.serial_line else None
    try:
        asyncio.run(_serve(cfg, line, counters, reconfigure, serve, faces, monitors))
    finally:
        if line is not None:
            line.close()


def _servers(cfg: SlaveConfig, inboxes: dict[str, Inbox]) -> ServerTargets | None:
    """The remote servers' thread, unstarted, its inboxes added to inboxes; None: no route
    reaches a server."""
    servers = server_targets(cfg)
    if not servers:
        return None
    thread = ServerTargets(servers, cfg.tcpto_ms, cfg.exception, cfg.upstream_tls)
    inboxes.update(thread.inboxes)
    return thread


async def _serve(cfg: SlaveConfig, line: SerialLine | None, counters: Counters,
                 reconfigure, serve, faces, monitors) -> None:
    mode = SlaveMode(cfg, line, counters, faces, monitors)
    await mode.listen()
    await serve(mode, reconfigure)


def _has_faces(cfg: SlaveConfig) -> bool:
    return any(line.is_face for line in cfg.lines)


class SlaveMode(ModeParts):
    """Slave mode's objects: line serial's worker, the Modbus TCP face, the target lines, the
    remote servers, the serial faces of the lines in master mode, the table."""

    def __init__(self, cfg: SlaveConfig, line: SerialLine | None, counters: Counters,
                 faces, monitors=None) -> None:
        super().__init__(cfg, None, counters)       # the status once listening (listen)
        self.devices = devices = DeviceHealth(rule=HealthRule(cfg.demotion))
        self.scheduler = Scheduler()
        self.tables = TableService(cfg, devices)
        self.inboxes: dict[str, Inbox] = {}     # every target's but the table's, by name
        self.targets = TargetLines(cfg, self.inboxes)
        self.servers = _servers(cfg, self.inboxes)
        worker: SlaveLineThread | FaceThread
        # one hub: every line's events, each naming its line
        self.server = TcpServer(cfg, self.scheduler, counters, lambda: worker.up, devices,
                                self.tables.table, self.inboxes, self.targets.hub)
        # a serial face may reach line serial, one a reload adds too
        self.serial_inbox = Inbox()
        self.serial_engine = Scenarios(serial_scenarios(cfg), self.tables.table, "serial")
        if cfg.serial_line:
            worker = SlaveLineThread(cfg, line, self.scheduler, self.server, counters, devices)
            worker.use_inbox(self.serial_inbox)
            worker.use_scenarios(self.serial_engine)  # run, and reconfigured, by the line thread
        else:   # no line serial to be the face's home
            worker = FaceThread(self.server, self.scheduler)
        self.worker = worker
        self._share_serial_inbox(cfg)
        self._make_faces = faces
        self.serial_faces: Any = None      # the serial faces (master.faces.LineFaces), once any
        if _has_faces(cfg):
            self._add_faces(cfg)
        self.load = LineLoad(lambda: counters.line_busy_ns)
        self.line_share = LineShare(counters, self.server.router.off_line, self.inboxes)
        self.addresses: list[str] = []
        self.running = cfg                 # the settings in force
        self._idle_ms = -1                 # the watchdog's idle limit, for lines added later
        self.engines["serial"] = self.serial_engine
        self.table, self.health, self.trace = self.tables.table, devices.rule, self.server.trace
        # the lines in monitor mode (monitor.lines.MonitorLines), once any
        self._make_monitors = monitors
        self.monitors: Any = monitors(cfg, self.tables.table, self.targets.hub) \
            if monitors is not None else None
        self._monitored = monitor_settings(cfg)
        self.commands.update(survey_commands(self.survey_lines))

    def survey_lines(self) -> dict[str, SurveyLine | str]:
        """Line serial and the target lines as `mbgw scan --line` finds them; the others'
        modes."""
        cfg = self.running
        lines: dict[str, SurveyLine | str] = {line.name: line.mode for line in cfg.lines}
        lines[PRIMARY_LINE] = SurveyLine(self.serial_inbox, cfg.serial)
        for name, target in list(self.targets.lines.items()):
            lines[name] = SurveyLine(target.inbox, target.config.serial)
        return lines

    def _share_serial_inbox(self, cfg: SlaveConfig) -> None:
        """Line serial's inbox among the targets' once the daemon has lines: before, line
        serial's figures are the daemon's (LineShare)."""
        if cfg.lines and cfg.serial_line:
            self.inboxes.setdefault(PRIMARY_LINE, self.serial_inbox)

    def _add_faces(self, cfg: SlaveConfig):
        """The serial faces of cfg's lines in master mode, unstarted (None: the daemon runs
        none)."""
        if self._make_faces is not None:
            self.serial_faces = self._make_faces(cfg, self.inboxes, self.tables.table,
                                                 self.targets.hub)
            if self.status is not None:
                self.status.faces = self.serial_faces
        return self.serial_faces

    async def listen(self) -> None:
        """The Modbus TCP face's listeners; then the status, which shows them."""
        try:
            self.addresses = await self.server.start()
        except ListenError:             # the TLS port's, named already
            raise
        except OSError as err:
            raise ListenError("mdbport", self.cfg.mdbport, err) from None
        self.status = SlaveStatus(self.cfg, self.server, self.worker, self.scheduler,
                                  self.counters, self.devices, self.addresses, self.tables,
                                  self.load)
        self.status.targets = self.targets
        self.status.line_share = self.line_share
        self.status.cache = self.server.cache
        self.status.faces = self.serial_faces
        self.status.monitors = self.monitors
        self.status.servers = self.server_rows

    def server_rows(self) -> list[dict]:
        """The remote servers the routes reach, as status and /metrics show them."""
        servers = self.servers        # a reload may replace them meanwhile
        return servers.status() if servers is not None else []

    def threads(self) -> list:
        faces = self.serial_faces.all() if self.serial_faces is not None else ()
        monitors = self.monitors.threads if self.monitors is not None else ()
        # the line threads, for the watchdog (the face's own thread has no line to watch)
        serial = [self.worker] if isinstance(self.worker, SlaveLineThread) else []
        return [*serial, *self.targets.threads(), *faces, *monitors]

    def collector(self, metrics, started: float):
        server = self.server
        collector = metrics.slave_collector(
            self.counters, self.devices, self.scheduler, server, self.worker, started,
            self.tables.figures, self.load,
            lambda: server.firewall.report() if server.firewall.configured else None,
            self.metered)
        collector.servers = self.server_rows
        collector.faces = server.face_figures
        return collector

    def metered(self) -> list[tuple]:
        """Each line's (name, counters, devices) for /metrics, line serial's first."""
        faces = self.serial_faces.metered() if self.serial_faces is not None else ()
        monitors = self.monitors.metered() if self.monitors is not None else ()
        serial = [(PRIMARY_LINE, self.line_share, self.devices)] if self.cfg.serial_line else []
        return [*serial, *self.targets.metered(), *faces, *monitors]

    def start(self, idle_ms: int) -> None:
        if isinstance(self.worker, SlaveLineThread):
            self.worker.idle_ms = idle_ms
        self.worker.start()
        self.targets.start(idle_ms)
        if self.servers is not None:
            self.servers.start()
        self._idle_ms = idle_ms
        if self.serial_faces is not None:
            self.serial_faces.start(idle_ms)
        if self.monitors is not None:
            self.monitors.start(idle_ms)

    def log_start(self) -> None:
        cfg = self.cfg
        s = cfg.serial
        if not cfg.serial_line:
            log.info("slave mode: listening on %s; no [serial]: lines %s%s",
                     ", ".join(self.addresses), ", ".join(line.name for line in cfg.lines),
                     origin(cfg))
            return
        log.info("slave mode: listening on %s; serial %s %d %s %s %s, stout %d ms%s%s",
                 ", ".join(self.addresses), s.device, s.baudrate, s.format, s.protocol,
                 s.wiring, s.stout_ms, ", nocheck" if s.nocheck else "", origin(cfg))
        if s.nocheck:
            log.warning("nocheck is on: serial replies are forwarded unchecked (a debugging "
                        "mode)")

    def tasks(self) -> tuple:
        return (self.tables.keep, self.load.keep)

    def lines(self) -> list[dict]:
        return self.status.lines()

    async def apply(self, new: SlaveConfig, report: ReloadReport) -> None:
        if new.serial_line != self.running.serial_line:
            report.refuse("serial", "[serial] added or left out takes effect at restart "
                                    "(systemctl restart mbgw)")
            new = dataclasses.replace(new, serial=self.running.serial)
        self._share_serial_inbox(new)
        self.tables.reconfigure(new, report)
        removed = await asyncio.to_thread(self.targets.reconfigure, new, report)
        retired = self._reface(new, report)
        old_servers = self._reserve(new)
        await self.server.reconfigure(new, report)
        await self._reroute(new)
        if retired:
            await asyncio.to_thread(self.serial_faces.retire, retired)
        for target in removed:
            target.stop()
            await asyncio.to_thread(target.join)
        if old_servers is not None:
            old_servers.stop()
            await asyncio.to_thread(old_servers.join_and_close)
        if monitor_settings(new) != self._monitored:
            self.monitors = await asyncio.to_thread(
                remonitor, self.monitors, self._make_monitors, new, self.tables.table,
                self.targets.hub, self._idle_ms, report)
            self.status.monitors = self.monitors
            self._monitored = monitor_settings(new)
        self.running = new

    async def _reroute(self, new: SlaveConfig) -> None:
        """The face routes to the targets in force from then on: line serial's thread swaps
        its routes between turns; the face's own thread reads them once a request, so they
        are swapped whole here."""
        worker = self.worker
        if isinstance(worker, FaceThread):
            self.server.route_face(new)
            return
        worker.configured.clear()
        worker.reconfigure(new)
        await asyncio.to_thread(worker.configured.wait, worker.turn_limit_s + 1)

    def _reface(self, new: SlaveConfig, report: ReloadReport) -> list:
        """The serial faces of new's lines in master mode: added, changed, removed.  Returns
        the removed ones, for the caller to retire."""
        if self.serial_faces is None:
            if not _has_faces(new):
                return []
            # the first line in master mode: reconfigure opens it (or tells the report)
            added = self._add_faces(dataclasses.replace(new, lines=()))
            if added is None:
                return []
            added.start(self._idle_ms)
        return self.serial_faces.reconfigure(new, report)

    def _reserve(self, new: SlaveConfig) -> ServerTargets | None:
        """The remote servers' thread anew when their settings changed; returns the old one,
        for the caller to stop once the face routes to the new one (None: kept)."""
        running = self.running
        if (new.tcpto_ms, new.exception, new.upstream_tls, how_reached(server_targets(new))) \
                == (running.tcpto_ms, running.exception, running.upstream_tls,
                    how_reached(server_targets(running))):
            return None
        old = self.servers
        for label in server_targets(running):
            self.inboxes.pop(label, None)
        self.servers = _servers(new, self.inboxes)
        if self.servers is not None:
            self.servers.start()
        return old

    async def stop(self) -> None:
        self.server.close()
        faces = self.serial_faces
        if faces is not None:
            faces.stop()
            await asyncio.to_thread(faces.join)
            faces.close()
        if self.monitors is not None:
            self.monitors.stop()
            await asyncio.to_thread(self.monitors.join)
            self.monitors.close()
        self.targets.stop()
        self.worker.stop()
        await asyncio.to_thread(self.worker.join)
        await asyncio.to_thread(self.targets.join)
        if self.servers is not None:
            self.servers.stop()
            await asyncio.to_thread(self.servers.join_and_close)
        self.tables.save()
        self.serial_engine.close()
        self.scheduler.close()

    def abandon(self) -> None:
        self.server.close()
