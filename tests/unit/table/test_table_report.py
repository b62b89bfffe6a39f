"""The exchange table's figures: table_status (mbgw.table.report) from a real Table, their
"table" section in `mbgw status` (mbgw.cli.render) and their /metrics families
(mbgw.ops.metrics), from hand-built dicts."""
import json
from types import SimpleNamespace

import prometheus_client
from prometheus_client import parser

from mbgw.cli.render import format_status
from mbgw.cli.render_table import table_section
from mbgw.config.model import TableConfig
from mbgw.ops.counters import Counters, MasterCounters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.ops.metrics import master_collector, slave_collector
from mbgw.table.memory import Table
from mbgw.table.report import table_status

NOW = 1_800_000_000.0


def test_table_status_counts_requests_by_function_and_outcome():
    table = Table()
    table.answer(bytes([0x03, 0x10, 0x00, 0x00, 0x02]))                  # FC 3: answered
    table.answer(bytes([0x03, 0xFF, 0xFF, 0x00, 0x02]))                  # beyond: 0x02
    table.answer(bytes([0x08, 0x00, 0x01, 0x00, 0x00]))                  # unknown: 0x01
    table.answer(bytes([0x06, 0x08, 0x00, 0x12, 0x34]), broadcast=True)   # broadcast write
    status = table_status(table)
    assert status["requests"]["3"] == {"answered": 1, "exception": 1, "broadcast": 0}
    assert status["requests"]["6"] == {"answered": 0, "exception": 0, "broadcast": 1}
    assert status["requests"]["8"] == {"answered": 0, "exception": 1, "broadcast": 0}
    assert set(status["requests"]) == {"1", "2", "3", "4", "5", "6", "7", "8", "15", "16",
                                       "23"}
    assert status["exceptions"] == {"0x01": 1, "0x02": 1}
    assert "serial" not in status and "persist" not in status and "units" not in status
    assert json.loads(json.dumps(status)) == status          # plain data, as the JSON carries


def test_table_status_with_settings_serial_and_persist():
    status = table_status(Table(), TableConfig(enabled=True, units=(1, 5, 200, 201, 202)),
                          serial={"requests": 7, "crc_errors": 1},
                          persist={"path": "/var/lib/t", "last_save": None})
    assert status["functions"] == [1, 2, 3, 4, 5, 6, 7, 15, 16, 23]
    assert (status["direct"], status["units"], status["address"], status["port"]) == \
        (True, "1,5,200-202", 0, 502)
    assert status["serial"] == {"requests": 7, "crc_errors": 1, "length_errors": 0,
                                "send_failures": 0}
    assert status["persist"] == {"path": "/var/lib/t", "last_save": None}
    assert status["enabled"] is True and "tcp" not in status
    assert table_status(Table(), tcp={"port": 502})["tcp"] == {"port": 502}


# --- mbgw status -----------------------------------------------------------------------------

def slave_status(table: dict | None) -> dict:
    status = {"version": "1.0", "mode": "slave", "pid": 42, "uptime_s": 5.0,
              "listening": ["0.0.0.0:502"],
              "serial": {"device": "/dev/ttyUSB0", "baudrate": 9600, "format": "8n1",
                         "protocol": "rtu", "interface": "rs232", "stout_ms": 600,
                         "state": "up"},
              "queue_depth": 0, "line_utilisation_pct": 0.0, "clients": [], "devices": [],
              "counters": {"requests": 3}, "counters_since": NOW}
    if table is not None:
        status["table"] = table
    return status


def requests(**rows) -> dict:
    base = {str(fc): {"answered": 0, "exception": 0, "broadcast": 0}
            for fc in (1, 2, 3, 4, 5, 6, 7, 15, 16, 23)}
    base.update({fc[2:]: dict(zip(("answered", "exception", "broadcast"), row, strict=True))
                 for fc, row in rows.items()})
    return base


def test_status_without_a_table_has_no_table_section():
    assert "table" not in format_status(slave_status(None), NOW)


def test_status_table_off():
    status = table_status(Table(), TableConfig(enabled=False))
    assert "\ntable      off\n" in format_status(slave_status(status), NOW)


def test_status_slave_table_section():
    text = format_status(slave_status({
        "functions": [3, 4, 6, 16], "direct": True, "units": "247-254", "address": 0,
        "port": 502, "requests": requests(fc3=(120, 2, 0), fc16=(5, 0, 3)),
        "exceptions": {"0x02": 2}}), NOW)
    lines = text.splitlines()
    start = lines.index("table      units 247-254 (direct), functions 3,4,6,16")
    assert lines[start + 1].split() == ["FC", "ANSWERED", "EXCEPTION", "BROADCAST"]
    assert lines[start + 2].split() == ["3", "120", "2", "0"]
    assert lines[start + 3].split() == ["16", "5", "0", "3"]
    assert lines[start + 4] == "  exceptions sent 0x02:2"
    assert text.index("table      ") < text.index("counters since")


def test_status_slave_table_without_direct_messaging_and_no_requests():
    text = format_status(slave_status({
        "functions": [3], "direct": False, "units": "247-254", "address": 0, "port": 502,
        "requests": requests(), "exceptions": {}}), NOW)
    assert "table      every unit (no direct messaging), functions 3\n  no requests yet\n" \
        in text
    assert "exceptions sent" not in text


def test_status_master_table_section_with_serial_slave_and_persist():
    table = {"functions": [3], "direct": True, "units": "247-254", "address": 17,
             "port": 1502, "requests": requests(fc3=(1, 0, 0)), "exceptions": {},
             "serial": {"requests": 9, "crc_errors": 1, "length_errors": 2,
                        "send_failures": 0},
             "persist": {"path": "/var/lib/mbgw/t", "last_save": NOW - 3.0, "saves": 4},
             "tcp": {"port": 1502, "connections": 2, "max_connections": 32,
                     "connections_accepted": 5, "connections_refused_limit": 1,
                     "connections_bad_header": 0}}
    lines = table_section(table, "master", NOW)
    assert "  TCP server: 2 of 32 clients, 5 accepted, 1 refused (limit), 0 closed (bad " \
        "header)" in lines
    assert lines[0] == "table      serial address 17, TCP port 1502, functions 3"
    assert "  serial slave: 9 requests, 1 invalid CRC, 2 invalid length, 0 failed sends" \
        in lines
    assert "  persist /var/lib/mbgw/t: last save 3.0s ago, saves 4" in lines
    assert not any("FAILING" in line for line in lines)


def test_status_master_table_section_with_its_tls_port():
    table = {"requests": requests(), "exceptions": {},
             "tcp": {"port": 1502, "connections": 0, "max_connections": 32,
                     "tls_port": 1802, "tls_handshakes": 1, "connections_refused_tls": 2}}
    lines = table_section(table, "master", NOW)
    assert "  TLS on port 1802: 1 handshakes under way, 2 refused, 0 closed before a byte" \
        in lines


def test_status_says_when_the_table_file_cannot_be_written():
    table = {"requests": requests(), "exceptions": {},
             "persist": {"path": "/var/lib/mbgw/table", "interval_s": 10,
                         "last_save": NOW - 90.0, "saves": 3,
                         "failing": "cannot write /var/lib/mbgw/table: Read-only file system",
                         "failing_since": NOW - 80.0}}
    lines = table_section(table, "slave", NOW)
    assert "  persist /var/lib/mbgw/table: every 10s, last save 1m30s ago, saves 3" in lines
    assert "  persist FAILING since 1m20s ago: cannot write /var/lib/mbgw/table: Read-only " \
        "file system (changes since the last save are not kept)" in lines


# --- /metrics --------------------------------------------------------------------------------

def families(collector) -> dict:
    registry = prometheus_client.CollectorRegistry()
    registry.register(collector)
    text = prometheus_client.generate_latest(registry).decode()
    return {f.name: f for f in parser.text_string_to_metric_families(text)}


def slave_metrics(table):
    return families(slave_collector(Counters(), DeviceHealth(), SimpleNamespace(depth=0),
                                    SimpleNamespace(clients=[]), SimpleNamespace(up=True), 0.0,
                                    table))


def test_metrics_table_requests_and_exceptions():
    status = {"requests": requests(fc3=(120, 2, 0), fc16=(5, 0, 3)),
              "exceptions": {"0x02": 2, "0x03": 1}}
    found = slave_metrics(lambda: status)
    values = {(s.labels["function"], s.labels["outcome"]): s.value
              for s in found["mbgw_table_requests"].samples}
    assert found["mbgw_table_requests"].type == "counter"
    assert values[("3", "answered")] == 120 and values[("3", "exception")] == 2
    assert values[("16", "broadcast")] == 3 and values[("23", "answered")] == 0
    assert len(values) == 10 * 3
    assert {s.labels["code"]: s.value for s in found["mbgw_table_exceptions"].samples} == \
        {"0x02": 2, "0x03": 1}
    assert all(s.name.endswith("_total") for f in ("mbgw_table_requests",
                                                   "mbgw_table_exceptions")
               for s in found[f].samples)
    assert "mbgw_table_serial_errors" not in found


def test_metrics_without_a_table_have_no_table_families():
    for found in (slave_metrics(None), slave_metrics(lambda: None)):
        assert not [name for name in found if name.startswith("mbgw_table")]


def test_metrics_master_serial_slave_errors():
    status = {"requests": requests(), "exceptions": {},
              "serial": {"requests": 9, "crc_errors": 1, "length_errors": 2,
                         "send_failures": 3}}
    found = families(master_collector(MasterCounters(), DeviceHealth(),
                                      SimpleNamespace(up=True, connections=lambda: []), 0.0,
                                      lambda: status))
    assert {s.labels["kind"]: s.value for s in found["mbgw_table_serial_errors"].samples} == \
        {"crc": 1, "length": 2, "send": 3}
    assert found["mbgw_table_serial_errors"].samples[0].name == "mbgw_table_serial_errors_total"
    assert found["mbgw_table_serial_requests"].samples[0].value == 9


def test_metrics_read_the_live_table_at_each_scrape():
    table = Table()
    collector = slave_collector(Counters(), DeviceHealth(), SimpleNamespace(depth=0),
                                SimpleNamespace(clients=[]), SimpleNamespace(up=True), 0.0,
                                lambda: table_status(table))
    table.answer(bytes([0x04, 0x00, 0x00, 0x00, 0x01]))
    first = {(s.labels["function"], s.labels["outcome"]): s.value
             for s in families(collector)["mbgw_table_requests"].samples}
    table.answer(bytes([0x04, 0x00, 0x00, 0x00, 0x01]))
    second = {(s.labels["function"], s.labels["outcome"]): s.value
              for s in families(collector)["mbgw_table_requests"].samples}
    assert (first[("4", "answered")], second[("4", "answered")]) == (1, 2)


def test_status_table_off_but_serving_the_scenarios_says_so():
    scenario = {"name": "boiler", "state": "running", "target": "slave 45", "function": 3,
                "trigger": "3000ms", "runs": 1, "errors": {}, "retries": 0, "overruns": 0,
                "last_latency_ms": 5.0, "data_age_s": 1.0, "last_success": NOW, "message": ""}
    status = slave_status(table_status(Table(), TableConfig(enabled=False)))
    status["scenarios"] = [scenario]
    text = format_status(status, NOW)
    assert "\ntable      on (scenarios): no Modbus client reaches it (table.enabled off)\n" \
        in text and "table      off" not in text
    master = slave_status(None)       # master mode reports no table while it is off
    master["scenarios"] = [scenario]
    assert "\ntable      on (scenarios)" in format_status(master, NOW)
