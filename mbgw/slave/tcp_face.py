"""The Modbus TCP face of a daemon with no line serial in slave mode (a master-mode daemon
whose `[[route]]`s take TCP units, a slave-mode one whose file leaves `[serial]` out): the
slave daemon's listener and router (TcpServer), at home on a thread of the face's own,
`mbgw-tcp-face`.

In a slave daemon line serial's thread polls the face's connections; here no thread owns a
line for the face, and its routes reach only other threads' targets (lines in slave mode,
remote servers) or the table.  So the face's thread is the gate's only holder: one poll() over
the clients and the wake-up eventfd, which both adopts new connections and delivers the
targets' outcomes (Router.deliver_completions) that came while it was busy, as line serial's
thread does; while it waits in that poll(), a target's thread delivers its own.
"""
import asyncio
import dataclasses
import logging
import threading
import time

from mbgw.config.lines import TCP_FACE, RouteConfig
from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth, HealthRule
from mbgw.ops.reload import ReloadReport
from mbgw.routing.queue import Inbox, Scheduler
from mbgw.slave.server import TcpServer
from mbgw.slave.servers import ServerTargets, how_reached

log = logging.getLogger("mbgw.tcp")

THREAD_NAME = "mbgw-tcp-face"


def has_tcp_face(cfg: MasterConfig) -> bool:
    """A master-mode daemon listens when some route is the TCP face's."""
    return any(r.face == TCP_FACE for r in cfg.routes)


def face_servers(cfg: MasterConfig) -> dict[str, RouteConfig]:
    """The servers the TCP face's routes reach, by target label (a serial face reaches its
    own on its thread)."""
    return {r.target: r for r in cfg.routes if r.server is not None and r.face == TCP_FACE}


def face_settings(cfg: MasterConfig) -> SlaveConfig:
    """The settings the TCP face reads, from a master-mode daemon's: `[net]` (mdbport, bind,
    authip, the limits, exception), `[tls]`, the firewall and the routes.  The table stays off
    in them: slave mode's `[table] units` are implicit routes, and this face has only the
    file's (the table itself is handed to TcpServer)."""
    return SlaveConfig(
        serial=cfg.serial, exception=cfg.exception, authip=cfg.authip, mdbport=cfg.mdbport,
        udp_port=cfg.udp_port, rtu_port=cfg.rtu_port, bind=cfg.bind,
        max_connections=cfg.max_connections, demotion=cfg.demotion,
        table=dataclasses.replace(cfg.table, enabled=False), firewall=cfg.firewall,
        tcpto_ms=cfg.tcpto_ms, tls=cfg.tls, request_timeout_ms=cfg.request_timeout_ms,
        location=cfg.location, lines=cfg.lines, routes=cfg.routes,
        gateway_unit=cfg.gateway_unit)


class FaceThread(threading.Thread):
    """The face's home: it serves the connections until stopped, then closes them."""

    up = False          # no line of its own: none of the face's units goes to line serial

    def __init__(self, server: TcpServer, scheduler: Scheduler) -> None:
        super().__init__(name=THREAD_NAME, daemon=True)
        self._connections = server.connections
        self._scheduler = scheduler
        self._stopping = False

    def stop(self) -> None:
        self._stopping = True
        self._scheduler.wake()

    def run(self) -> None:
        connections = self._connections
        try:
            while not self._stopping:
                try:
                    connections.wait(-1)
                except Exception:   # a bug must cost this wake-up, never the face
                    log.exception("internal error on the Modbus TCP face")
        finally:
            connections.close_all()


class TcpFace:
    """The listeners, the router and the face's thread, as the master daemon holds them."""

    def __init__(self, cfg: MasterConfig, inboxes: dict[str, Inbox], table, hub) -> None:
        """inboxes: the targets' (lines in slave mode, servers), the dict the daemon keeps up
        to date; table: the exchange table (None: off); hub: the daemon's trace hub.  Raises
        ConfigError (the TLS files)."""
        self.counters = Counters()
        self._inboxes = inboxes
        self._servers = self._serve_servers(cfg)
        self._scheduler = Scheduler()      # nothing queues in it: its eventfd wakes the face
        settings = face_settings(cfg)
        devices = DeviceHealth(rule=HealthRule(cfg.demotion))   # no line of its own
        self.server = TcpServer(settings, self._scheduler, self.counters, lambda: FaceThread.up,
                                devices, table, inboxes, hub)
        self._thread = FaceThread(self.server, self._scheduler)
        self.addresses: list[str] = []

    async def listen(self) -> list[str]:
        """Raises ListenError."""
        self.addresses = await self.server.start()
        return self.addresses

    def _serve_servers(self, cfg: MasterConfig) -> ServerTargets:
        """The remote servers' threads, unstarted, their inboxes among the targets'."""
        self._reached = self._made_of(cfg)
        servers = ServerTargets(face_servers(cfg), cfg.tcpto_ms, cfg.exception,
                                cfg.upstream_tls)
        self._inboxes.update(servers.inboxes)
        return servers

    @staticmethod
    def _made_of(cfg: MasterConfig) -> tuple:
        return cfg.tcpto_ms, cfg.exception, cfg.upstream_tls, how_reached(face_servers(cfg))

    def start(self) -> None:
        self._servers.start()
        self._thread.start()

    async def reconfigure(self, cfg: MasterConfig, report: ReloadReport) -> None:
        """New settings; the servers' threads anew when theirs changed (the old ones stopped
        once the face routes to the new)."""
        old = None
        if self._made_of(cfg) != self._reached:
            old = self._servers
            for label in old.inboxes:
                self._inboxes.pop(label, None)
            self._servers = self._serve_servers(cfg)
            self._servers.start()
        settings = face_settings(cfg)
        await self.server.reconfigure(settings, report)
        self.server.route_face(settings)     # swapped whole: the face reads it once a request
        self.addresses = self.server.addresses()
        if old is not None:
            old.stop()
            await asyncio.to_thread(old.join_and_close)

    def clients(self) -> list[dict]:
        """The connected clients, as slave mode's status lists them."""
        now, mono = time.time(), time.monotonic()
        return [{"id": c.id, "peer": c.peer, "connected_since": c.connected_at,
                 "requests": c.requests, "in_flight": c.in_flight,
                 "firewall_refused": c.firewall_refused,
                 "last_activity": now - (mono - c.last_active),
                 "listener": c.listener, "role": c.role} for c in self.server.clients]

    def faces(self) -> dict[str, dict[str, int]]:
        """Each listener's figures (plain, tls, udp, rtu), as slave mode's status has them."""
        return self.server.face_figures()

    def close_client(self, client_id: int, user=None) -> bool:
        return self.server.close_client(client_id, user)

    def stop(self) -> None:
        self.server.close()
        self._thread.stop()

    def join(self) -> None:
        if self._thread.is_alive():
            self._thread.join()
        self._servers.stop()
        self._servers.join_and_close()
        self._scheduler.close()
