"""Slave mode's daemon: opens line serial, listens (the Modbus TCP face), builds the target
lines, the remote servers and the serial faces; the skeleton that runs them is
mbgw.gateway.skeleton's."""
import asyncio
import logging

from mbgw.config.lines import PRIMARY_LINE
from mbgw.config.model import SlaveConfig
from mbgw.errors import ListenError
from mbgw.line.port import SerialLine
from mbgw.line.supervisor import open_at_start
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceTable, HealthRule
from mbgw.ops.load import LineLoad
from mbgw.ops.reload import ReloadReport
from mbgw.ops.service import ModeParts, origin
from mbgw.routing.inbox import Inbox
from mbgw.scenarios.engine import Scenarios
from mbgw.slave.line_thread import LineWorker, serial_scenarios
from mbgw.slave.routes import effective_routes
from mbgw.slave.scheduler import Scheduler
from mbgw.slave.server import TcpServer
from mbgw.slave.servers import ServerTargets, server_targets
from mbgw.slave.status import SlaveStatus
from mbgw.slave.table_service import TableService
from mbgw.slave.targets import TargetLines

log = logging.getLogger("mbgw")


def run_slave(cfg: SlaveConfig, reconfigure, serve, faces=None) -> None:
    """Raises SerialError when the device is there and cannot be opened (one that is not there
    yet is waited for), ListenError when mdbport cannot be bound; otherwise returns after
    SIGTERM or SIGINT.  reconfigure() gives the settings to apply on SIGHUP (None: there is no
    file to reload).  serve(parts, reconfigure): the daemon's skeleton
    (mbgw.gateway.skeleton.serve_mode).  faces(cfg, routes, inboxes, table): the serial faces'
    threads, unstarted (mbgw.gateway's, when some line is in master mode)."""
    counters = Counters()
    line = open_at_start(cfg.serial, counters)
    try:
        asyncio.run(_serve(cfg, line, counters, reconfigure, serve, faces))
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


async def _serve(cfg: SlaveConfig, line: SerialLine | None, counters: Counters,
                 reconfigure, serve, faces) -> None:
    mode = SlaveMode(cfg, line, counters, faces)
    await mode.listen()
    await serve(mode, reconfigure)


class SlaveMode(ModeParts):
    """Slave mode's objects: line serial's worker, the Modbus TCP face, the target lines, the
    remote servers, the serial faces of the lines in master mode, the table."""

    def __init__(self, cfg: SlaveConfig, line: SerialLine | None, counters: Counters,
                 faces) -> None:
        self.devices = devices = DeviceTable(rule=HealthRule(cfg.demotion))
        self.scheduler = Scheduler()
        self.tables = TableService(cfg, devices)
        self.inboxes: dict[str, Inbox] = {}     # every target's but the table's, by name
        self.targets = TargetLines(cfg, self.inboxes)
        self.servers = _servers(cfg, self.inboxes)
        worker: LineWorker
        self.server = TcpServer(cfg, self.scheduler, counters, lambda: worker.up, devices,
                                self.tables.table, self.inboxes)
        self.worker = worker = LineWorker(cfg, line, self.scheduler, self.server, counters,
                                          devices)
        if cfg.lines:                      # a serial face may reach line serial too
            self.inboxes[PRIMARY_LINE] = Inbox()
            worker.use_inbox(self.inboxes[PRIMARY_LINE])
        self.serial_faces = faces(cfg, effective_routes(cfg), self.inboxes,
                                  self.tables.table) if faces is not None else []
        self.serial_engine = Scenarios(serial_scenarios(cfg), self.tables.table, "serial")
        worker.use_scenarios(self.serial_engine)    # run, and reconfigured, by the line thread
        self.load = LineLoad(lambda: counters.line_busy_ns)
        self.addresses: list[str] = []
        self.running = cfg                 # the settings in force
        super().__init__(cfg, None, counters)
        self.engines["serial"] = self.serial_engine
        self.table, self.health, self.trace = self.tables.table, devices.rule, self.server.trace

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

    def threads(self) -> list:
        return [self.worker, *self.targets.threads(), *self.serial_faces]

    def collector(self, metrics, started: float):
        server = self.server
        return metrics.slave_collector(
            self.counters, self.devices, self.scheduler, server, self.worker, started,
            self.tables.figures, self.load,
            lambda: server.firewall.report() if server.firewall.configured else None)

    def start(self, idle_ms: int) -> None:
        self.worker.idle_ms = idle_ms
        self.worker.start()
        self.targets.start(idle_ms)
        if self.servers is not None:
            self.servers.start()
        for face in self.serial_faces:
            face.idle_ms = idle_ms
            face.start()

    def log_start(self) -> None:
        cfg = self.cfg
        s = cfg.serial
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
        self.tables.reconfigure(new, report)
        removed = await asyncio.to_thread(self.targets.reconfigure, new, report)
        old_servers = self._reserve(new)
        await self.server.reconfigure(new, report)
        worker = self.worker
        worker.configured.clear()
        worker.reconfigure(new)        # the face routes to the targets in force from then on
        await asyncio.to_thread(worker.configured.wait, worker.turn_limit_s + 1)
        for target in removed:
            target.stop()
            await asyncio.to_thread(target.join)
        if old_servers is not None:
            old_servers.stop()
            await asyncio.to_thread(old_servers.join_and_close)
        self.running = new

    def _reserve(self, new: SlaveConfig) -> ServerTargets | None:
        """The remote servers' thread anew when their settings changed; returns the old one,
        for the caller to stop once the face routes to the new one (None: kept)."""
        running = self.running
        if (new.tcpto_ms, new.exception, server_targets(new)) == \
                (running.tcpto_ms, running.exception, server_targets(running)):
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
        for face in self.serial_faces:
            face.stop()
        for face in self.serial_faces:
            await asyncio.to_thread(face.join)
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
