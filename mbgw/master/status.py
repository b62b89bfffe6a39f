"""What the running master-mode daemon reports through the control socket (the commands
both modes share are in mbgw.ops.status)."""
from typing import Any

from mbgw.config.route_plan import route_map, routes_status
from mbgw.master.faces import Faces
from mbgw.ops.status import DaemonStatus
from mbgw.scenarios.report import scenarios_status


class MasterStatus(DaemonStatus):
    """Master mode: the serial master's addresses, the slaveid table, the upstream servers."""
    mode = "master"

    def __init__(self, cfg, slave, counters, tables) -> None:
        super().__init__(cfg, counters, slave.devices, slave.hub)
        self._slave = slave
        self._tables = tables
        self.scenario_engines: dict = {}    # the scenarios' engines by kind (the daemon's)
        self.faces: Faces | None = None     # every line in master mode
        self.targets = None     # the lines in slave mode (slave.targets.TargetLines), if any
        self.tcp_face: Any = None    # the Modbus TCP face (slave.tcp_face.TcpFace), if any
        self.monitors: Any = None    # the lines in monitor mode (monitor.lines.MonitorLines)

    def status(self, request: dict) -> dict:
        cfg = self.cfg
        data = self._common()
        data["serial"]["state"] = self._slave.state
        return {
            **data,
            "upstream": {"port": cfg.mdbport, "tcpto_ms": cfg.tcpto_ms,
                         "exception": cfg.exception, "max_connections": cfg.max_connections,
                         "connections": self._slave.connections()},
            "slaveid": [{"first": r.first, "last": r.last, "remote_first": r.remote_first,
                         "variable_ip": r.variable_ip, "ip": str(r.ip), "tls": r.tls,
                         "route": str(r)}
                        for r in cfg.slaveid.ranges],
            "counters": self._counters.snapshot(),
            "counters_since": self._reset_at,
            "devices": [d.snapshot() for d in self._devices.all()],
            "lines": self.lines(),
            "routes": routes_status(route_map(cfg)),
            "table": self._tables.figures(self._slave.table_counters.snapshot()),
            "clients": self._tables.clients(),
            **self._tcp_face(),
            **({"firewall": firewall} if (firewall := self._tables.firewall_report()) else {}),
            **({"scenarios": rows} if (rows := scenarios_status(self.scenario_engines.values()))
               else {}),
        }

    def _tcp_face(self) -> dict:
        """The Modbus TCP face's listeners, clients and counters, when it runs."""
        face = self.tcp_face
        if face is None:
            return {}
        return {"listening": face.addresses, "tcp_clients": face.clients(),
                "tcp_counters": face.counters.snapshot(), "faces": face.faces()}

    def lines(self) -> list[dict]:
        """Every line: line serial and the others in master mode (faces), then those in
        slave mode (targets)."""
        faces = self.faces.all() if self.faces is not None else [self._slave]
        return [*(face.status() for face in faces),
                *(self.targets.status() if self.targets is not None else ()),
                *(self.monitors.status() if self.monitors is not None else ())]

    def commands(self) -> dict:
        return {**super().commands(), **self._tables.commands()}

    def reset(self, request: dict) -> dict:
        self._slave.table_counters.reset()
        self._tables.reset_counts()
        return super().reset(request)

    def summary(self) -> str:
        c = self._counters
        face = self.tcp_face
        clients = f"{len(face.server.clients)} clients, " if face is not None else ""
        return (f"master mode: line {'up' if self._slave.up else 'down'}, {clients}"
                f"{len(self._slave.connections())} server connections, {c.requests} requests, "
                f"{c.timeouts} timeouts")

    def close(self, request: dict) -> dict:
        """A client of the Modbus TCP face, else of the table's server (the connections to
        the servers are not clients)."""
        face = self.tcp_face
        client_id = request.get("client")
        if face is not None and isinstance(client_id, int) and \
                face.close_client(client_id, request.get("uid")):
            return {"ok": True}
        if not self._tables.cfg.enabled:
            return {"error": "clients close: master mode's only Modbus TCP clients are the "
                             "exchange table's, and the table is off (--table)"}
        return self.close_table_client(self._tables, request)
