"""The serial faces of a master-mode daemon: line serial's (`[serial]`) and those of the
other lines in master mode (`[[line]]`), each a thread of its own (mbgw.master.serial_face),
opened, started, stopped and closed together; a reload adds, changes and removes the
others."""
import logging

from mbgw.config.model import MasterConfig, SlaveConfig
from mbgw.config.route_plan import RouteMap
from mbgw.errors import SerialError
from mbgw.line.supervisor import open_at_start
from mbgw.master.face_routes import face_settings
from mbgw.master.serial_face import SerialFace, build_face
from mbgw.ops.counters import MasterCounters
from mbgw.ops.reload import ReloadReport
from mbgw.ops.trace import TraceHub

log = logging.getLogger("mbgw")


class LineFaces:
    """The serial faces of the lines in master mode beside serial (`[[line]]`), by name,
    each on its own thread: opened at start, added, changed and removed by a reload.  In a
    master-mode daemon beside line serial's face (Faces), in a slave-mode one alone.
    inboxes: the target lines' Inbox by name (the caller's dict, which the faces look up at
    each request)."""

    def __init__(self, cfg: SlaveConfig | MasterConfig, inboxes: dict, table,
                 hub: TraceHub | None = None) -> None:
        """hub: the daemon's trace hub.  Raises SerialError (what was opened closed)."""
        self.faces: dict[str, SerialFace] = {}
        self._inboxes = inboxes
        self._table = table
        self._hub = hub
        self._idle_ms = -1
        try:
            routes = RouteMap(cfg.routes)
            for line in face_lines(cfg).values():
                self._add(line, cfg, routes)
        except BaseException:
            self.close()
            raise

    def _add(self, line, cfg: SlaveConfig | MasterConfig, routes: RouteMap) -> SerialFace:
        face = self.faces[line.name] = build_face(line, cfg, routes, self._inboxes,
                                                  self._table, self._hub)
        log.info("line %s: master mode, serial %s %d %s %s; %d routes", line.name,
                 line.serial.device, line.serial.baudrate, line.serial.format,
                 line.serial.protocol, sum(r.face == line.name for r in cfg.routes))
        return face

    def all(self) -> list[SerialFace]:
        return list(self.faces.values())      # a reload may be adding

    def status(self) -> list[dict]:
        return [face.status() for face in self.all()]

    def metered(self) -> list[tuple]:
        """Each line's (name, counters, devices) for /metrics."""
        return [(face.face, face.counters, face.devices) for face in self.all()]

    def start(self, idle_ms: int) -> None:
        self._idle_ms = idle_ms
        for face in self.all():
            face.idle_ms = idle_ms
            face.start()

    def reconfigure(self, cfg: SlaveConfig | MasterConfig,
                    report: ReloadReport | None = None) -> list[SerialFace]:
        """New settings for every face whose line is still there in master mode; lines
        added are opened and started (one whose device is there and does not open is told
        to the report).  Returns the faces removed: the caller stops, joins and closes them
        (retire) once nothing routes through them."""
        routes = RouteMap(cfg.routes)
        wanted = face_lines(cfg)
        removed = [self.faces.pop(name) for name in list(self.faces) if name not in wanted]
        for name, line in wanted.items():
            face = self.faces.get(name)
            if face is not None:
                face.reconfigure_line(line, cfg, routes)
                continue
            try:
                face = self._add(line, cfg, routes)
            except SerialError as err:        # a device there that does not open
                log.error("line %s not opened: %s", name, err.strerror or err)
                if report is not None:
                    report.refuse("lines", f"line {name}: {err.strerror or err}")
                continue
            face.idle_ms = self._idle_ms
            face.start()
        return removed

    @staticmethod
    def retire(faces: list[SerialFace]) -> None:
        """Faces a reload removed: stopped, joined, their devices released."""
        for face in faces:
            face.stop()
        for face in faces:
            if face.is_alive():
                face.join()
            face.close()

    def stop(self) -> None:
        for face in self.all():
            face.stop()

    def join(self) -> None:
        for face in self.all():
            if face.is_alive():
                face.join()

    def close(self) -> None:
        for face in self.all():
            face.close()


class Faces:
    """Line serial's face and the faces of the other lines in master mode (LineFaces): a
    master-mode daemon's."""

    def __init__(self, primary: SerialFace, others: LineFaces) -> None:
        self.primary = primary
        self.others = others

    @classmethod
    def opened(cls, cfg: MasterConfig, counters: MasterCounters, table,
               inboxes: dict | None = None) -> "Faces":
        """Every face, its device open (or waited for).  Raises SerialError (what was
        opened closed)."""
        inboxes = inboxes if inboxes is not None else {}
        line = open_at_start(cfg.serial)
        try:
            primary = SerialFace(face_settings(cfg, None, RouteMap(cfg.routes)), line,
                                 counters, table, inboxes)
        except BaseException:
            if line is not None:
                line.close()
            raise
        try:
            others = LineFaces(cfg, inboxes, table, primary.hub)
        except BaseException:
            primary.close()
            raise
        return cls(primary, others)

    def all(self) -> list[SerialFace]:
        return [self.primary, *self.others.all()]

    def metered(self) -> list[tuple]:
        """Each line's (name, counters, devices) for /metrics, line serial's first."""
        return [(f.face, f.counters, f.devices) for f in self.all()]

    def start(self, idle_ms: int) -> None:
        self.primary.idle_ms = idle_ms
        self.primary.start()
        self.others.start(idle_ms)

    def reconfigure(self, cfg: MasterConfig,
                    report: ReloadReport | None = None) -> list[SerialFace]:
        """As LineFaces.reconfigure, line serial's face given its new settings too."""
        self.primary.reconfigure(face_settings(cfg, None, RouteMap(cfg.routes)))
        return self.others.reconfigure(cfg, report)

    def stop(self) -> None:
        self.primary.stop()
        self.others.stop()

    def join(self) -> None:
        if self.primary.is_alive():
            self.primary.join()
        self.others.join()

    def close(self) -> None:
        self.primary.close()
        self.others.close()


def face_lines(cfg: SlaveConfig | MasterConfig) -> dict:
    """The lines in master mode beside serial, by name."""
    return {line.name: line for line in cfg.lines if line.is_face}
