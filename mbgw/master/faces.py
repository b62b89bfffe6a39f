"""The serial faces of a master-mode daemon: line serial's (`[serial]`) and those of the
other lines in master mode (`[[line]]`), each a thread of its own (mbgw.master.serial_face),
opened, started, reconfigured, stopped and closed together."""
import logging

from mbgw.config.lines import RouteMap
from mbgw.config.model import MasterConfig
from mbgw.line.supervisor import open_at_start
from mbgw.master.face_routes import face_settings
from mbgw.master.serial_face import SerialFace, build_face
from mbgw.ops.counters import MasterCounters

log = logging.getLogger("mbgw")


class Faces:
    """Line serial's face and the faces of the other lines in master mode (`[[line]]`), each
    on its own thread; the status and the metrics show line serial's."""

    def __init__(self, primary: SerialFace) -> None:
        self.primary = primary
        self.others: dict[str, SerialFace] = {}

    @classmethod
    def opened(cls, cfg: MasterConfig, counters: MasterCounters, table) -> "Faces":
        """Every face, its device open (or waited for).  Raises SerialError (what was
        opened closed)."""
        line = open_at_start(cfg.serial)
        try:
            primary = SerialFace(face_settings(cfg, None, RouteMap(cfg.routes)), line,
                                 counters, table)
        except BaseException:
            if line is not None:
                line.close()
            raise
        faces = cls(primary)
        try:
            faces._build_others(cfg, table)
        except BaseException:
            faces.close()
            raise
        return faces

    def _build_others(self, cfg: MasterConfig, table) -> None:
        routes = RouteMap(cfg.routes)
        for line in cfg.lines:
            if not line.is_face:
                log.error("line %s: a line in slave mode does not run in a master-mode "
                          "daemon yet: requests routed to it get 0x0A or silence", line.name)
                continue
            self.others[line.name] = build_face(line, cfg, routes, {}, table, self.primary.hub)
            log.info("line %s: master mode, serial %s %d %s %s; %d routes", line.name,
                     line.serial.device, line.serial.baudrate, line.serial.format,
                     line.serial.protocol, sum(r.face == line.name for r in cfg.routes))

    def metered(self) -> list[tuple]:
        """Each line's (name, counters, devices) for /metrics, line serial's first."""
        return [(self.primary.face, self.primary.counters, self.primary.devices),
                *((name, face.counters, face.devices) for name, face in self.others.items())]

    def start(self, idle_ms: int) -> None:
        for face in (self.primary, *self.others.values()):
            face.idle_ms = idle_ms
            face.start()

    def reconfigure(self, cfg: MasterConfig) -> None:
        """New settings for every face whose line is still there in master mode; lines
        added, removed or turned to slave mode take a restart."""
        routes = RouteMap(cfg.routes)
        self.primary.reconfigure(face_settings(cfg, None, routes))
        lines = {line.name: line for line in cfg.lines if line.is_face}
        for name, face in self.others.items():
            if name in lines:
                face.reconfigure_line(lines[name], cfg, routes)
        changed = lines.keys() ^ self.others.keys()
        if changed:
            log.warning("lines %s: adding or removing a line in master mode takes a "
                        "restart", ", ".join(sorted(changed)))

    def stop(self) -> None:
        for face in (self.primary, *self.others.values()):
            face.stop()

    def join(self) -> None:
        for face in (self.primary, *self.others.values()):
            if face.is_alive():
                face.join()

    def close(self) -> None:
        for face in (self.primary, *self.others.values()):
            face.close()
