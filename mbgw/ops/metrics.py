"""What `--metrics` says: the daemon's counters as Prometheus metric families, each mode's
collector putting the sections together (each in a metrics_* module of its own: lines,
devices, table, faces, remote_servers, scenarios, mqtt).

`DaemonCollector` turns the live objects into metric families at each scrape, as `mbgw
status` reads them, so the two always agree and the line path never calls prometheus_client;
the table, the firewall and the scenarios give theirs as the status's plain dicts.  Serving
them over HTTP is mbgw.ops.metrics_server.
"""
from collections.abc import Callable

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from mbgw import __version__
from mbgw.config.lines import PRIMARY_LINE
from mbgw.ops.metrics_devices import device_families
from mbgw.ops.metrics_faces import face_families, firewall_family
from mbgw.ops.metrics_lines import (
    cache_families,
    counter_help,
    line_counter_families,
    line_up_family,
    load_gauges,
)
from mbgw.ops.metrics_mqtt import mqtt_families
from mbgw.ops.metrics_remote_servers import server_families
from mbgw.ops.metrics_scenarios import scenario_families
from mbgw.ops.metrics_table import table_families


def daemon_families(mode: str, started: float):
    """The daemon's version, mode and start."""
    info = GaugeMetricFamily("mbgw_info", "mbgw's version and mode (always 1).",
                             labels=["version", "mode"])
    info.add_metric([__version__, mode], 1)
    yield info
    yield GaugeMetricFamily("mbgw_start_time_seconds", "When the daemon started (Unix time).",
                            value=round(started, 3))


class DaemonCollector:
    """A prometheus_client collector of a daemon's live objects.  They are read in the
    scrape's thread while the line thread may be counting: a scrape is a snapshot within a
    transaction.  gauges() gives (name, help, value) of the mode's own gauges; table(), when
    the daemon serves the exchange table, its status dict (mbgw.table.report.table_status)."""

    def __init__(self, counters, devices, started: float, mode: str, up, gauges,
                 table=None, firewall=None,
                 scenarios=None, lines=None) -> None:
        self._counters = counters
        self._devices = devices
        # () -> (name, counters, device table) of each line: the per-line families' samples,
        # each labelled line="NAME" (line serial's too)
        self._lines = lines if lines is not None else \
            (lambda: [(PRIMARY_LINE, counters, devices)])
        self._started = started
        self._mode = mode
        self._gauges = gauges
        self._table = table
        self._firewall = firewall       # the firewall's status dict (mbgw.firewall), or None
        self.scenarios = scenarios      # () -> the status's "scenarios" rows, or None
        # () -> the status's "lines" rows, whose state says each line's mbgw_line_up; until
        # the daemon gives them, line serial's alone, up() saying its state
        # () -> the remote servers the TCP face's routes reach: "server" and "counters"
        # (mbgw.slave.servers), or None
        self.servers: Callable[[], list[dict]] | None = None
        # () -> northbound MQTT's status (mbgw.northbound.counters), or None: MQTT off
        self.mqtt: Callable[[], dict | None] | None = None
        # () -> the Modbus TCP face's figures by listener (the status's "faces"), or None
        self.faces: Callable[[], dict | None] | None = None
        self.lines: Callable[[], list[dict]] = lambda: [
            {"name": PRIMARY_LINE, "mode": mode, "state": "up" if up() else "down"}]

    def collect(self):
        yield from daemon_families(self._mode, self._started)
        lines = list(self._lines())
        yield from line_counter_families(lines, self._mode == "master")
        rows = self.lines()
        yield line_up_family(rows)
        yield from cache_families(rows)
        for name, help_text, value in self._gauges():
            yield GaugeMetricFamily(name, help_text, value=value)
        table = [(name, d) for name, _, devices in lines for d in devices.all()]
        yield from device_families(table, self._devices.counts, self._mode == "master")
        status = self._table() if self._table is not None else None
        if status is not None:
            yield from table_families(status)
        firewall = self._firewall() if self._firewall is not None else None
        if firewall is not None:
            yield firewall_family(firewall)
        if self.scenarios is not None:
            yield from scenario_families(self.scenarios())
        if self.servers is not None:
            yield from server_families(self.servers())
        mqtt = self.mqtt() if self.mqtt is not None else None
        if mqtt is not None:
            yield from mqtt_families(mqtt)
        faces = self.faces() if self.faces is not None else None
        if faces:
            yield from face_families(faces)


def slave_collector(counters, devices, scheduler, server, worker,
                    started: float, table=None, load=None, firewall=None,
                    lines=None) -> DaemonCollector:
    """Slave mode's metrics; table(): the exchange table's status dict, when it is on; load:
    the line's load (mbgw.ops.load.LineLoad); lines(): every line's (name, counters,
    devices), line serial's first (None: line serial only)."""
    return DaemonCollector(counters, devices, started, "slave", lambda: worker.up, lambda: [
        *load_gauges(load),
        ("mbgw_queue_depth", "Requests waiting for the serial line.", scheduler.depth),
        ("mbgw_clients_connected", "Modbus TCP clients connected.", len(server.clients))],
        table, firewall, lines=lines)


def master_collector(counters, devices, slave, started: float,
                     table=None, firewall=None, lines=None, clients=None) -> DaemonCollector:
    """Master mode's metrics; table(): the exchange table's status dict, when it is on;
    lines() as slave_collector's; clients(): the Modbus TCP face's clients, None while the
    daemon has no such face."""
    return DaemonCollector(counters, devices, started, "master", lambda: slave.up, lambda: [
        ("mbgw_upstream_connections", "Connections open to Modbus TCP servers.",
         len(slave.connections())),
        *([("mbgw_clients_connected", "Modbus TCP clients connected.", connected)]
          if clients is not None and (connected := clients()) is not None else [])],
        table, firewall, lines=lines)


_TRANSPARENT_HELP = {
    "frames_received": "Complete frames received on the line (CRC errors included).",
    "frames_stored": "Frames stored at rx-address.",
    "frames_truncated": "Frames stored cut to rx-size.",
    "frames_incomplete": "Frames dropped: the line went quiet for eof-timeout before their end.",
    "crc_errors": "Frames dropped for a wrong CRC (--crc).",
    "frames_sent": "Frames sent from the tx area.",
    "sends_refused": "Changes of the tx area that held no whole frame: nothing sent.",
    "raw_bytes_in": "Bytes from the raw-port client to the line.",
    "raw_bytes_out": "Bytes of frames from the line to the raw-port client.",
    "raw_bytes_dropped": "Bytes of frames the raw-port client did not take in time.",
    "raw_refused": "raw-port clients refused (one at a time; authip).",
}


class TransparentCollector:
    """Transparent mode's metrics, from its status dicts: figures() (mbgw.transparent.status)
    and table() (mbgw.table.report)."""

    def __init__(self, line, figures, started: float, table) -> None:
        self._line = line               # .up, .counters
        self._figures = figures
        self._started = started
        self._table = table

    def collect(self):
        yield from daemon_families("transparent", self._started)
        yield line_up_family([{"name": PRIMARY_LINE, "mode": "transparent",
                               "state": "up" if self._line.up else "down"}])
        figures = self._figures()
        for name, value in self._line.counters.snapshot().items():
            help_text = _TRANSPARENT_HELP.get(name) or counter_help(name)
            prefix = "mbgw_transparent_" if name in _TRANSPARENT_HELP else "mbgw_"
            family = CounterMetricFamily(prefix + name, help_text, labels=["line"])
            family.add_metric([PRIMARY_LINE], value)
            yield family
        yield GaugeMetricFamily("mbgw_transparent_raw_client_connected",
                                "1 while a raw-port client is connected.",
                                value=int(figures["raw_client"] is not None))
        yield from table_families(self._table())


def transparent_collector(line, figures, started: float, table) -> TransparentCollector:
    return TransparentCollector(line, figures, started, table)

