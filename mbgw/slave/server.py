"""Slave mode's network side: the Modbus TCP server on mdbport (and tls-port), in two halves
that meet at the thread seam.

- mbgw.slave.listener (the asyncio thread): listening, accept and admission, eviction, the
  request deadlines, the reload of the listeners, the operator's close.
- mbgw.slave.router (the line thread, and the table reader under the gate): each request
  routed, answered at once or queued for the line, and each outcome sent back.

An admitted connection is handed from the first to the second through Connections (the line
thread's poll over the clients).  TcpServer puts the three together and is what the daemon,
the line thread (SlaveLineThread) and the status hold.
"""
from collections import Counter

from mbgw.config.model import SlaveConfig
from mbgw.firewall.guard import Firewall
from mbgw.ops.counters import Counters, FaceCounters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.ops.reload import ReloadReport
from mbgw.ops.trace import TraceHub
from mbgw.routing.cache import ReadCache
from mbgw.routing.queue import Inbox, Scheduler
from mbgw.slave.connections import Client, Connections
from mbgw.slave.listener import (  # noqa: F401 (the names tests and docs know here)
    FIRST_REQUEST_S,
    SLOW_REQUEST_S,
    Listener,
    eviction_victim,
    slow,
)
from mbgw.slave.router import OUTCOME_FIREWALL, Router  # noqa: F401


class TcpServer:
    def __init__(self, cfg: SlaveConfig, scheduler: Scheduler, counters: Counters,
                 line_up, devices: DeviceHealth, table=None,
                 inboxes: dict[str, Inbox] | None = None, trace: TraceHub | None = None) -> None:
        """line_up: callable, is the serial line usable?  table: the exchange table
        (mbgw.table.memory.Table), served while cfg.table is enabled.  inboxes: the other
        targets' (lines by name, servers by target label), a dict the daemon keeps up to
        date before each reconfigure().  trace: the daemon's hub (None: one of its own).
        Raises ConfigError (the TLS files)."""
        self.counters = counters
        self.trace = trace if trace is not None else TraceHub()
        firewall = Firewall(cfg.firewall, cfg.tls.roles_required)
        self.router = Router(cfg, scheduler, counters, line_up, devices, firewall, self.trace,
                             table, inboxes)
        self.connections = Connections(scheduler.wake_fd, self.router.request, self._closed,
                                       counters)
        self.connections.on_wake = self.router.deliver_completions
        self.router.connections = self.connections
        self.listener = Listener(cfg, counters, self.connections, firewall,
                                 self.router.request)
        self.table = table
        self._table_functions = cfg.table.functions
        # the line thread's and the table reader's entry points
        self.request = self.router.request
        self.read_meanwhile = self.router.read_meanwhile
        self.take_kept = self.router.take_kept
        self.taken = self.router.taken
        self.finished = self.router.finished
        self.traced_late = self.router.traced_late
        self.traced = self.router.traced
        self.route_face = self.router.route_face

    @property
    def firewall(self) -> Firewall:
        return self.listener.firewall

    @property
    def clients(self) -> list[Client]:
        return self.listener.clients

    @property
    def faces(self) -> dict[str, FaceCounters]:
        """The figures of each listener (plain, tls, udp, rtu)."""
        return self.listener.faces

    def face_figures(self) -> dict[str, dict[str, int]]:
        """Each listener's figures and its clients now (UDP: the sources it remembers)."""
        clients = Counter(c.listener for c in self.clients)
        clients["udp"] = sum(p.sources for p in self.listener.udp_ports)
        return {listener: {**face.snapshot(), "clients": clients[listener]}
                for listener, face in self.faces.items()}

    @property
    def inboxes(self) -> dict[str, Inbox]:
        return self.router.inboxes

    @property
    def cache(self) -> ReadCache:
        return self.router.cache

    @property
    def shortcut_allowed(self) -> bool:
        return self.router.shortcut_allowed

    @property
    def reads_meanwhile(self) -> bool:
        return self.router.reads_meanwhile

    async def start(self) -> list[str]:
        """Listen; returns the listening addresses.  Raises ListenError."""
        return await self.listener.start()

    def addresses(self) -> list[str]:
        return self.listener.addresses()

    async def reconfigure(self, cfg: SlaveConfig, report: ReloadReport) -> None:
        """Apply new settings; connections they do not concern stay open (Listener's)."""
        if self.table is not None and cfg.table.functions != self._table_functions:
            self.table.set_functions(cfg.table.functions)
        self._table_functions = cfg.table.functions
        await self.listener.reconfigure(cfg, report)
        self.router.reconfigure(cfg, self.listener.firewall)

    def close_client(self, client_id: int, user=None) -> bool:
        return self.listener.close_client(client_id, user)

    def close(self) -> None:
        self.listener.close()

    def _closed(self, client: Client) -> None:
        """Line thread: client's connection has ended."""
        self.router.closed(client)
        self.listener.forget_soon(client)
