"""The daemon's listen-only lines (`[[line]]` with `mode = "monitor"`), each a thread of its
own, composed by mbgw.gateway.daemon for both daemon modes.  A monitor line is neither face
nor target: no route reaches it and it takes no request; it only stores what it hears."""
import logging

from mbgw.line.supervisor import open_at_start
from mbgw.monitor.line_thread import MonitorLineThread, listening, transmitter_off
from mbgw.monitor.store import MapStore

log = logging.getLogger("mbgw.monitor")


class _NoDevices:
    """A monitor line keeps no device books (nothing is asked of a device)."""
    @staticmethod
    def all() -> list:
        return []


class MonitorLines:
    def __init__(self, cfg, table, hub) -> None:
        """cfg: the daemon's settings (SlaveConfig or MasterConfig); table: the exchange
        table (on whenever a map is there); hub: the daemon's trace hub.  Raises SerialError
        when a device is there and does not open."""
        self.threads: list[MonitorLineThread] = []
        try:
            for line in (x for x in cfg.lines if x.is_monitor):
                settings = listening(line)
                maps = tuple(m for m in cfg.monitors if m.line == line.name)
                port = open_at_start(settings.serial)
                self.threads.append(MonitorLineThread(
                    settings, None if port is None else transmitter_off(port),
                    MapStore(maps, table), hub.for_line(line.name)))
        except BaseException:
            self.close()
            raise

    def status(self) -> list[dict]:
        return [t.status() for t in self.threads]

    def metered(self) -> list[tuple]:
        return [(t.line_name, t.counters, _NoDevices) for t in self.threads]

    def start(self, idle_ms: int) -> None:
        for t in self.threads:
            t.idle_ms = idle_ms
            t.start()
            log.info("line %s: listening on %s (monitor mode: mbgw never transmits)",
                     t.line_name, t.device)

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
