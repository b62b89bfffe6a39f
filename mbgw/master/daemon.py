"""Master mode's daemon: opens the lines, serves the serial masters (the serial faces), runs
the lines in slave mode it is handed (targets), the Modbus TCP face it is handed (when routes
take TCP units) and the table; the skeleton that runs them
(signals, control socket, metrics, reload, systemd's watchdog) is mbgw.gateway.skeleton's."""
import asyncio
import dataclasses
import logging
from typing import Any

from mbgw.config.lines import PRIMARY_LINE
from mbgw.config.model import MasterConfig
from mbgw.config.monitor import monitor_settings
from mbgw.errors import ConfigError, ListenError
from mbgw.master.faces import Faces, LineFaces
from mbgw.master.status import MasterStatus
from mbgw.master.table_service import TableService
from mbgw.ops.counters import MasterCounters
from mbgw.ops.reload import ReloadReport
from mbgw.ops.service import ModeParts, origin, remonitor
from mbgw.routing.survey import SurveyLine, survey_commands

log = logging.getLogger("mbgw")
TICK_S = 1.0        # how often the table's file is looked at (it is saved per its interval)


def run_master(cfg: MasterConfig, reconfigure, serve, targets=None, tcp_face=None,
               monitors=None) -> None:
    """Raises SerialError when the device is there and cannot be opened (one that is not
    there yet is waited for), ListenError when the metrics address, table-port or
    tls-port cannot be listened on; otherwise returns after SIGTERM or SIGINT.
    reconfigure() gives the settings to apply on SIGHUP (None: there is no file to reload).
    serve(parts, reconfigure): the daemon's skeleton (mbgw.gateway.skeleton.serve_mode).
    targets(cfg, inboxes): the lines in slave mode, unstarted, their inboxes added to inboxes
    (mbgw.gateway's slave.targets.TargetLines), called when there are any, at start or at a
    reload; None: such lines do not run.  tcp_face(cfg, inboxes, table, hub): the Modbus TCP
    face (mbgw.gateway's slave.tcp_face.TcpFace) when routes take TCP units, else None; it
    raises ListenError when mdbport or tls-port cannot be listened on.  monitors(cfg, table,
    hub): the lines in monitor mode, unstarted, or None."""
    counters = MasterCounters()
    tables = TableService(cfg)
    inboxes: dict = {}                 # the lines in slave mode's, by name
    faces = Faces.opened(cfg, counters, tables.table, inboxes)
    try:
        tables.start()
        mode = MasterMode(cfg, faces, counters, tables, targets, inboxes, tcp_face, monitors)
        asyncio.run(_serve(mode, reconfigure, serve))
    finally:
        tables.stop()
        faces.close()


async def _serve(mode: "MasterMode", reconfigure, serve) -> None:
    await mode.listen()
    await serve(mode, reconfigure)


def _has_targets(cfg: MasterConfig) -> bool:
    return any(line.is_target for line in cfg.lines)


def table_address(cfg: MasterConfig) -> int:
    """The serial address the table answers as; 0: none."""
    return cfg.table.address if cfg.table.enabled else 0


def _line_modes(cfg: MasterConfig) -> dict[str, str]:
    """Each line's mode by name, line serial (a serial face) included."""
    return {PRIMARY_LINE: "master", **{line.name: line.mode for line in cfg.lines}}


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


class MasterMode(ModeParts):
    """Master mode's objects: the serial faces, the lines in slave mode (targets, when the
    gateway hands them), the table's service."""

    def __init__(self, cfg: MasterConfig, faces: Faces, counters: MasterCounters,
                 tables: TableService, targets, inboxes: dict, tcp_face=None,
                 monitors=None) -> None:
        slave = faces.primary
        super().__init__(cfg, MasterStatus(cfg, slave, counters, tables), counters)
        self.faces = faces
        self.tables = tables
        self._make_targets = targets
        self._inboxes = inboxes
        self._idle_ms = -1
        self.targets: Any = None       # the lines in slave mode (TargetLines), once any
        if _has_targets(cfg):
            self._add_targets(cfg)
        self._make_tcp_face = tcp_face
        self.tcp_face: Any = None      # the Modbus TCP face (slave.tcp_face.TcpFace), once any
        self.status.faces = faces
        self.table, self.health, self.trace = tables.table, slave.devices.rule, slave.hub
        # the lines in monitor mode (monitor.lines.MonitorLines), once any
        self._make_monitors = monitors
        self.monitors: Any = \
            monitors(cfg, tables.table, slave.hub) if monitors is not None else None
        self.status.monitors = self.monitors
        self._monitored = monitor_settings(cfg)
        self._modes = _line_modes(cfg)
        self.commands.update(survey_commands(self.survey_lines))

    def survey_lines(self) -> dict[str, SurveyLine | str]:
        """The lines in slave mode as `mbgw scan --line` finds them; the others' modes."""
        lines: dict[str, SurveyLine | str] = dict(self._modes)
        if self.targets is not None:
            for name, target in list(self.targets.lines.items()):
                lines[name] = SurveyLine(target.inbox, target.config.serial)
        return lines

    def _add_targets(self, cfg: MasterConfig) -> Any:
        """The lines in slave mode of cfg, unstarted (None: the daemon runs none)."""
        if self._make_targets is None:
            for line in cfg.lines:
                if line.is_target:
                    log.error("line %s: a line in slave mode does not run in this daemon: "
                              "requests routed to it get 0x0A or silence", line.name)
            return None
        self.targets = self.status.targets = self._make_targets(cfg, self._inboxes,
                                                                  self.faces.primary.hub)
        return self.targets

    async def listen(self) -> None:
        """The Modbus TCP face's listeners, when routes take TCP units.  Raises ListenError."""
        await self._add_tcp_face(self.cfg)

    async def _add_tcp_face(self, cfg: MasterConfig) -> Any:
        """The face, listening (None: cfg has none, or it runs already)."""
        if self._make_tcp_face is None or self.tcp_face is not None:
            return None
        # the gateway unit answers from the table even while it is off
        answers = cfg.table_on or cfg.gateway_unit
        face = self._make_tcp_face(cfg, self._inboxes, self.tables.table if answers else None,
                                   self.faces.primary.hub)
        if face is not None:
            await face.listen()
            self.tcp_face = self.status.tcp_face = face
        return face

    def threads(self) -> list:
        return [*self.faces.all(), *(self.targets.threads() if self.targets is not None else ()),
                *(self.monitors.threads if self.monitors is not None else ())]

    def collector(self, metrics, started: float):
        slave, tables = self.faces.primary, self.tables
        collector = metrics.master_collector(
            self.counters, slave.devices, slave, started,
            lambda: tables.figures(slave.table_counters.snapshot()), tables.firewall_report,
            self.metered, self._tcp_clients)
        collector.faces = lambda: self.tcp_face.faces() if self.tcp_face is not None else None
        return collector

    def _tcp_clients(self) -> int | None:
        face = self.tcp_face
        return len(face.server.clients) if face is not None else None

    def metered(self) -> list[tuple]:
        """Each line's (name, counters, devices) for /metrics, line serial's first."""
        targets = self.targets.metered() if self.targets is not None else ()
        monitors = self.monitors.metered() if self.monitors is not None else ()
        return [*self.faces.metered(), *targets, *monitors]

    def start(self, idle_ms: int) -> None:
        self._idle_ms = idle_ms
        if self.targets is not None:
            self.targets.start(idle_ms)
        if self.tcp_face is not None:
            self.tcp_face.start()
        self.faces.start(idle_ms)
        if self.monitors is not None:
            self.monitors.start(idle_ms)

    def log_start(self) -> None:
        cfg = self.cfg
        s = cfg.serial
        log.info("master mode: serial %s %d %s %s %s; servers' port %d, tcpto %d ms, "
                 "exception %s, at most %d connections; slaveid %s%s", s.device, s.baudrate,
                 s.format, s.protocol, s.wiring, cfg.mdbport, cfg.tcpto_ms,
                 "on" if cfg.exception else "off", cfg.max_connections, cfg.slaveid,
                 origin(cfg))
        _log_slaveid(cfg)
        if self.tcp_face is not None:
            log.info("Modbus TCP face: listening on %s", ", ".join(self.tcp_face.addresses))

    def tasks(self) -> tuple:
        return (lambda: _tick(self.tables),)

    def lines(self) -> list[dict]:
        return self.status.lines()

    async def apply(self, new: MasterConfig, report: ReloadReport) -> None:
        _log_slaveid(new)
        self._modes = _line_modes(new)
        self.tables.reconfigure(new, report)
        if self.targets is None and _has_targets(new):
            # the first line in slave mode: reconfigure opens it (or tells the report)
            added = self._add_targets(dataclasses.replace(new, lines=()))
            if added is not None:
                added.start(self._idle_ms)
        removed = await asyncio.to_thread(self.targets.reconfigure, new, report) \
            if self.targets is not None else []
        await self._reface(new, report)
        retired = self.faces.reconfigure(new, report)   # they route to the lines in force
        await asyncio.to_thread(LineFaces.retire, retired)
        for target in removed:
            target.stop()
            await asyncio.to_thread(target.join)
        if monitor_settings(new) != self._monitored:
            self.monitors = self.status.monitors = await asyncio.to_thread(
                remonitor, self.monitors, self._make_monitors, new, self.tables.table,
                self.faces.primary.hub, self._idle_ms, report)
            self._monitored = monitor_settings(new)

    async def _reface(self, new: MasterConfig, report: ReloadReport) -> None:
        """The Modbus TCP face: added by the first route of its, reconfigured after (it keeps
        listening, its routes taking nothing, when the file has none left)."""
        if self.tcp_face is not None:
            await self.tcp_face.reconfigure(new, report)
            return
        try:
            face = await self._add_tcp_face(new)
        except (ListenError, ConfigError) as err:
            report.refuse("mdbport", f"the Modbus TCP face cannot start: {err}")
            return
        if face is not None:
            face.start()

    async def stop(self) -> None:
        if self.tcp_face is not None:
            self.tcp_face.stop()
            await asyncio.to_thread(self.tcp_face.join)
        self.faces.stop()
        await asyncio.to_thread(self.faces.join)
        if self.monitors is not None:
            self.monitors.stop()
            await asyncio.to_thread(self.monitors.join)
            self.monitors.close()
        if self.targets is not None:
            self.targets.stop()
            await asyncio.to_thread(self.targets.join)
