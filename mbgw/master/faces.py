"""The serial faces of a master-mode daemon: line serial's (`[serial]`) and those of the
other lines in master mode (`[[line]]`), each a thread of its own (mbgw.master.serial_face),
opened, started, stopped and closed together; a reload adds, changes and removes the
others."""
import logging

from mbgw.config.lines import RouteMap
from mbgw.config.model import MasterConfig
from mbgw.errors import SerialError
from mbgw.line.supervisor import open_at_start
from mbgw.master.face_routes import face_settings
from mbgw.master.serial_face import SerialFace, build_face
from mbgw.ops.counters import MasterCounters
from mbgw.ops.reload import ReloadReport

log = logging.getLogger("mbgw")


class Faces:
    """Line serial's face and the faces of the other lines in master mode (`[[line]]`), each
    on its own thread; a reload adds and removes the others.  inboxes: the target lines'
    Inbox by name (the caller's dict, which the faces look up at each request)."""

    def __init__(self, primary: SerialFace, inboxes: dict, table) -> None:
        self.primary = primary
        self.others: dict[str, SerialFace] = {}
        self._inboxes = inboxes
        self._table = table
        self._idle_ms = -1

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
        faces = cls(primary, inboxes, table)
        try:
            routes = RouteMap(cfg.routes)
            for line_cfg in face_lines(cfg).values():
                faces._add(line_cfg, cfg, routes)
        except BaseException:
            faces.close()
            raise
        return faces

    def _add(self, line, cfg: MasterConfig, routes: RouteMap) -> SerialFace:
        face = self.others[line.name] = build_face(line, cfg, routes, self._inboxes,
                                                   self._table)
        log.info("line %s: master mode, serial %s %d %s %s; %d routes", line.name,
                 line.serial.device, line.serial.baudrate, line.serial.format,
                 line.serial.protocol, sum(r.face == line.name for r in cfg.routes))
        return face

    def all(self) -> list[SerialFace]:
        return [self.primary, *list(self.others.values())]   # a reload may be adding

    def start(self, idle_ms: int) -> None:
        self._idle_ms = idle_ms
        for face in self.all():
            face.idle_ms = idle_ms
            face.start()

    def reconfigure(self, cfg: MasterConfig,
                    report: ReloadReport | None = None) -> list[SerialFace]:
        """New settings for every face whose line is still there in master mode; lines
        added are opened and started (one whose device is there and does not open is told
        to the report).  Returns the faces removed: the caller stops, joins and closes them
        (see retire)."""
        routes = RouteMap(cfg.routes)
        self.primary.reconfigure(face_settings(cfg, None, routes))
        wanted = face_lines(cfg)
        removed = [self.others.pop(name) for name in list(self.others) if name not in wanted]
        for name, line in wanted.items():
            face = self.others.get(name)
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


def retire(faces: list[SerialFace]) -> None:
    """Faces a reload removed: stopped, joined, their devices released."""
    for face in faces:
        face.stop()
    for face in faces:
        if face.is_alive():
            face.join()
        face.close()


def face_lines(cfg: MasterConfig) -> dict:
    """The lines in master mode beside serial, by name."""
    return {line.name: line for line in cfg.lines if line.is_face}
