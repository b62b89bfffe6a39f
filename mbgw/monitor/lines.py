"""The daemon's listen-only lines (`[[line]]` with `mode = "monitor"`), each a thread of its
own, composed by mbgw.gateway.daemon for both daemon modes.  A monitor line is neither face
nor target: no route reaches it and it takes no request; it only stores what it hears.  A
reload adds, removes and changes them (reconfigure) while the others keep listening."""
import logging

from mbgw.errors import SerialError
from mbgw.line.supervisor import open_at_start
from mbgw.monitor.line_thread import MonitorLineThread, listening, transmitter_off
from mbgw.monitor.store import MapStore

log = logging.getLogger("mbgw.monitor")


class _NoDevices:
    """A monitor line keeps no device books (nothing is asked of a device)."""
    @staticmethod
    def all() -> list:
        return []


def _maps_of(cfg, name: str) -> tuple:
    return tuple(m for m in cfg.monitors if m.line == name)


class MonitorLines:
    def __init__(self, cfg, table, hub) -> None:
        """cfg: the daemon's settings (SlaveConfig or MasterConfig); table: the exchange
        table (on whenever a map is there); hub: the daemon's trace hub.  Raises SerialError
        when a device is there and does not open."""
        self._table = table
        self._hub = hub
        self._idle_ms = -1               # the watchdog's idle limit, for lines added later
        self.threads: list[MonitorLineThread] = []
        try:
            for line in (x for x in cfg.lines if x.is_monitor):
                self.threads.append(self._opened(cfg, line))
        except BaseException:
            self.close()
            raise

    def _opened(self, cfg, line) -> MonitorLineThread:
        """line's thread, its port opened (or waited for); raises SerialError."""
        settings = listening(line)
        port = open_at_start(settings.serial)
        return MonitorLineThread(settings, None if port is None else transmitter_off(port),
                                 MapStore(_maps_of(cfg, line.name), self._table),
                                 self._hub.for_line(line.name))

    def status(self) -> list[dict]:
        return [t.status() for t in list(self.threads)]

    def metered(self) -> list[tuple]:
        return [(t.line_name, t.counters, _NoDevices) for t in list(self.threads)]

    def start(self, idle_ms: int) -> None:
        self._idle_ms = idle_ms
        for t in self.threads:
            self._start(t)

    def _start(self, t: MonitorLineThread) -> None:
        t.idle_ms = self._idle_ms
        t.start()
        log.info("line %s: listening on %s (monitor mode: mbgw never transmits)",
                 t.line_name, t.device)

    def reconfigure(self, cfg, report=None) -> None:
        """cfg's monitor lines from now on (blocking: a worker thread's call).  A line whose
        port settings are the same keeps listening, with its new maps; one removed or
        changed stops and releases its device first, then the added and changed ones open
        (one that is there and does not open is told to the report, the others run)."""
        wanted = {line.name: line for line in cfg.lines if line.is_monitor}
        kept, retired = [], []
        for t in self.threads:
            line = wanted.get(t.line_name)
            if line is not None and listening(line) == t.settings:
                kept.append(t)
                maps = _maps_of(cfg, t.line_name)
                if maps != t.store.maps:
                    t.use_maps(MapStore(maps, self._table))
            else:
                retired.append(t)
        self.threads = kept        # the watchdog looks at these only from now on
        for t in retired:
            t.stop()
        for t in retired:
            if t.is_alive():
                t.join()
            t.close_line()
            log.info("line %s: no longer listened to", t.line_name)
        running = {t.line_name for t in kept}
        for name, line in wanted.items():
            if name in running:
                continue
            try:
                added = self._opened(cfg, line)
            except SerialError as err:       # a device there that does not open
                log.error("line %s not opened: %s", name, err.strerror or err)
                if report is not None:
                    report.refuse("lines", f"line {name}: {err.strerror or err}")
                continue
            self._start(added)
            self.threads = [*self.threads, added]

    def stop(self) -> None:
        for t in self.threads:
            t.stop()

    def join(self) -> None:
        for t in self.threads:
            if t.is_alive():
                t.join()

    def close(self) -> None:
        for t in self.threads:
            if not t.is_alive():
                t.close_line()
