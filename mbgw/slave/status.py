"""What the running slave-mode daemon reports through the control socket: status and client
close (the commands both modes share are in mbgw.ops.status)."""
import time
from collections.abc import Callable

from mbgw.config.lines import PRIMARY_LINE, LineConfig
from mbgw.config.route_plan import routes_status
from mbgw.ops.load import LineLoad, average_percent
from mbgw.ops.status import DaemonStatus, line_row, settings_row
from mbgw.routing.cache import ReadCache
from mbgw.scenarios.report import scenarios_status
from mbgw.slave.line_share import LineShare
from mbgw.slave.routes import effective_routes
from mbgw.slave.targets import TargetLines


class SlaveStatus(DaemonStatus):
    """Slave mode: TCP clients, the queue, the serial slaves."""
    mode = "slave"

    def __init__(self, cfg, server, worker, scheduler, counters, devices, addresses,
                 tables=None, load: LineLoad | None = None) -> None:
        super().__init__(cfg, counters, devices, server.trace)
        self.load = load or LineLoad(lambda: counters.line_busy_ns)   # the line's load now
        self._tables = tables           # the exchange table (mbgw.slave.table_service)
        self._server = server
        self._worker = worker
        self._scheduler = scheduler
        self._addresses = addresses
        self.line_share: LineShare | None = None    # line serial's own figures (the daemon's)
        self.scenario_engines: dict = {}    # the scenarios' engines by kind (the daemon's)
        self.targets: TargetLines | None = None     # the lines beside serial (the daemon's)
        self.cache: ReadCache | None = None     # line serial's read cache (the daemon's)
        self.faces = None       # the lines in master mode (master.faces.LineFaces), if any
        self.monitors = None    # the lines in monitor mode (monitor.lines.MonitorLines), if any
        # () -> the remote servers the routes reach (slave.servers.ServerThread.status)
        self.servers: Callable[[], list[dict]] = list

    def commands(self) -> dict:
        tables = self._tables
        return {**super().commands(), **(tables.commands() if tables is not None else {})}

    def reset(self, request: dict) -> dict:
        self._server.firewall.reset_counts()
        if self.line_share is not None:
            self.line_share.reset()
        if self._tables is not None:
            self._tables.table.reset_counts()
        return super().reset(request)

    def trace_header(self) -> dict:
        return {**super().trace_header(), "listening": self._addresses}

    def status(self, request: dict) -> dict:
        now, mono = time.time(), time.monotonic()
        counters = self._counters.snapshot()
        busy_ns = counters.pop("line_busy_ns")
        data = self._common()
        if self.cfg.serial_line:
            data["serial"].update(stout_ms=self.cfg.serial.stout_ms, state=self._worker.state)
        else:       # [serial] left out: its settings are only the [[line]]s' defaults
            del data["serial"]
        table = self._tables.figures() if self._tables is not None else None
        firewall = self._server.firewall
        return {
            **data, "listening": self._addresses,
            **({"table": table} if table is not None else {}),
            **({"firewall": firewall.report(
                (c.peer, c.role, c.firewall_refused) for c in self._server.clients)}
               if firewall.configured else {}),
            "faces": self._server.face_figures(),
            "queue_depth": self._scheduler.depth,
            "clients": [{"id": c.id, "peer": c.peer, "connected_since": c.connected_at,
                         "requests": c.requests, "in_flight": c.in_flight,
                         "firewall_refused": c.firewall_refused,
                         "last_activity": now - (mono - c.last_active),
                         "listener": c.listener, "role": c.role}
                        for c in self._server.clients],
            "counters": counters,
            "counters_since": self._reset_at,
            "line_utilisation_pct": average_percent(busy_ns, mono - self._reset_mono),
            "line_load_pct": self.load.percent(),
            "devices": (devices := [d.snapshot() for d in self._devices.all()]),
            "lines": self._lines(devices),
            "routes": routes_status(effective_routes(self.cfg)),
            "servers": self.servers(),
            **({"scenarios": rows} if (rows := scenarios_status(self.scenario_engines.values()))
               else {}),
        }

    def lines(self) -> list[dict]:
        """The "lines" rows, as the metrics read them."""
        return self._lines([d.snapshot() for d in self._devices.all()])

    def _lines(self, devices: list[dict]) -> list[dict]:
        counters = (self.line_share or self._counters).snapshot()
        serial = [line_row(PRIMARY_LINE, self.cfg.serial.device, "slave", self._worker.state,
                           counters, devices,
                           self.cache.status() if self.cache is not None else None,
                           settings_row(self._serial_line()), self._worker.state_since)
                  ] if self.cfg.serial_line else []
        return [*serial, *(self.targets.status() if self.targets is not None else ()),
                *(self.faces.status() if self.faces is not None else ()),
                *(self.monitors.status() if self.monitors is not None else ())]

    def _serial_line(self) -> LineConfig:
        """Line serial as the [[line]]s are: [serial] and the timing of the daemon's."""
        cfg = self.cfg
        return LineConfig(PRIMARY_LINE, cfg.serial, retries=cfg.retries,
                          demotion=cfg.demotion, cache=cfg.cache)

    def summary(self) -> str:
        c = self._counters
        line = f"line {'up' if self._worker.up else 'down'}" if self.cfg.serial_line else \
            f"{len(self.cfg.lines)} lines"
        return (f"slave mode: {line}, "
                f"{len(self._server.clients)} clients, {c.requests} requests, "
                f"{c.timeouts} timeouts")

    def close(self, request: dict) -> dict:
        client_id = request.get("client")
        if not isinstance(client_id, int):
            return {"error": "close needs a client id"}
        if self._server.close_client(client_id, request.get("uid")):
            return {"ok": True}
        return {"error": f"no client {client_id}"}
