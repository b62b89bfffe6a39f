"""What status, trace and /metrics show of a slave-mode daemon with two lines (issue 24):
each line's row, counters and devices, `status --line`, the trace events named by line and
`trace --line` (decoded and raw) narrowed to one, and per-line metric samples.

Peers that are not ours: pymodbus RTU slaves on socat pty pairs recording what their line
carried; the trace is read from the control socket as `mbgw trace` reads it, the metrics
over HTTP with prometheus_client's parser.  The rig is test_lines.py's.
"""
import json
import os

import pytest

from mbgw.ops import control
from tests.harness import PtyPair, free_port, read_pty
from tests.integration.lines import test_lines as rig
from tests.modbus import read_holding, rtu_frame
from tests.ops import mbgw, metric_value, scraped, status
from tests.wait import until

pytestmark = pytest.mark.integration

lines = rig.lines              # the rig's fixtures, used here as they are
gateway = rig.gateway
EVENT_WAIT_S = 5.0             # the deadline for a trace event that is due


class TraceStream:
    """A trace subscription on the control socket: its header, then its events as JSON."""

    def __init__(self, gw, raw: bool = False, **filters) -> None:
        self.sock = control.connect(gw.control, timeout=EVENT_WAIT_S)
        self.sock.sendall(json.dumps({"command": "trace", "raw": raw,
                                      "filters": filters}).encode() + b"\n")
        self.file = self.sock.makefile("rb")
        self.header = json.loads(self.file.readline())

    def events(self, n: int) -> list[dict]:
        return [json.loads(self.file.readline()) for _ in range(n)]

    def close(self) -> None:
        self.file.close()
        self.sock.close()


@pytest.fixture
def two_lines(lines, gateway):
    serial, meters = lines("serial", rig.SERIAL_SLAVE), lines("meters", rig.METER)
    port = free_port()
    gw = gateway(serial, rig.meters_spec(meters), "--exception",
                 "--metrics", f"127.0.0.1:{port}")
    return gw, serial, meters, port


def test_status_shows_each_line_and_narrows_to_one(two_lines, client):
    gw, serial, meters, _ = two_lines
    c = client(gw)
    assert c.ask(rig.SERIAL_SLAVE, read_holding(0, 1)) == rig.hr_reply(0, 1)
    assert c.ask(rig.METER_UNIT, read_holding(3, 2)) == rig.hr_reply(3, 2)
    assert rig.received(meters.record) == [bytes((rig.METER,)) + read_holding(3, 2)]
    s = status(gw)
    rows = {row["name"]: row for row in s["lines"]}
    assert rows["meters"]["counters"]["requests"] == 1
    assert [(d["line"], d["address"], d["replies"]) for d in rows["meters"]["devices"]] == \
        [("meters", rig.METER, 1)]
    assert [(d["line"], d["address"]) for d in rows["serial"]["devices"]] == \
        [("serial", rig.SERIAL_SLAVE)]

    one = mbgw("status", "--line", "meters", "--json", "--control", gw.control)
    assert one.returncode == 0, one.stderr
    narrowed = json.loads(one.stdout)
    assert narrowed["line"]["name"] == "meters"
    assert {(r["units"], r["target"]) for r in narrowed["routes"]} == \
        {("32-63", "line meters")}
    text = mbgw("status", "--line", "meters", "--control", gw.control).stdout
    assert "devices of line meters (1)" in text and "line serial" not in text, text
    assert "devices of line meters (1)" in mbgw("status", "--control", gw.control).stdout

    unknown = mbgw("status", "--line", "tanks", "--control", gw.control)
    assert unknown.returncode == 1
    assert "tanks" in unknown.stderr and "serial, meters" in unknown.stderr, unknown.stderr


def test_trace_names_the_line_and_narrows_to_one(two_lines, client):
    gw, serial, meters, _ = two_lines
    everything = TraceStream(gw)
    only_meters = TraceStream(gw, line="meters")
    raw_meters = TraceStream(gw, raw=True, line="meters")
    try:
        assert everything.header["lines"] == ["serial", "meters"]
        c = client(gw)
        assert c.ask(rig.SERIAL_SLAVE, read_holding(0, 1)) == rig.hr_reply(0, 1)
        assert c.ask(rig.METER_UNIT, read_holding(3, 2)) == rig.hr_reply(3, 2)
        seen = [(e["line"], e["direction"], e["unit"], e["remote"] == e["peer"])
                for e in everything.events(4)]
        assert seen == [("serial", "request", rig.SERIAL_SLAVE, True),
                        ("serial", "reply", rig.SERIAL_SLAVE, True),
                        ("meters", "request", rig.METER_UNIT, True),
                        ("meters", "reply", rig.METER_UNIT, True)]
        narrowed = only_meters.events(2)
        assert [(e["line"], e["direction"], e["unit"], e["pdu"]) for e in narrowed] == \
            [("meters", "request", rig.METER_UNIT, read_holding(3, 2).hex()),
             ("meters", "reply", rig.METER_UNIT, rig.hr_reply(3, 2).hex())]
        bursts = raw_meters.events(2)     # the bytes on line meters: address 1, not 32
        assert [(b["line"], b["kind"]) for b in bursts] == [("meters", "request"),
                                                            ("meters", "reply")]
        assert bytes.fromhex(bursts[0]["bytes"])[:-2] == \
            rig.received(meters.record)[0] == bytes((rig.METER,)) + read_holding(3, 2)
    finally:
        for stream in (everything, only_meters, raw_meters):
            stream.close()

    unknown = mbgw("trace", "--line", "tanks", "--count", "1", "--control", gw.control)
    assert unknown.returncode != 0
    assert "'tanks'" in unknown.stderr and "serial, meters" in unknown.stderr, unknown.stderr


def test_metrics_carry_each_line(two_lines, client):
    gw, serial, meters, port = two_lines
    c = client(gw)
    assert c.ask(rig.METER_UNIT, read_holding(3, 2)) == rig.hr_reply(3, 2)
    assert c.ask(rig.METER_UNIT, read_holding(0, 1)) == rig.hr_reply(0, 1)
    assert c.ask(rig.SERIAL_SLAVE, read_holding(0, 1)) == rig.hr_reply(0, 1)

    def scrape_once_booked():
        """The books are kept after a reply has gone (C forwards it first)."""
        found = scraped(port)
        booked = (metric_value(found, "mbgw_transaction_latency_seconds",
                               "mbgw_transaction_latency_seconds_count", line="meters",
                               address=rig.METER) >= 2
                  and metric_value(found, "mbgw_device_replies", "mbgw_device_replies_total",
                                   line="serial", address=rig.SERIAL_SLAVE) >= 1)
        return found if booked else None

    found = until(scrape_once_booked, "the three transactions booked", 5)
    assert metric_value(found, "mbgw_requests", "mbgw_requests_total", line="meters") == 2
    # line serial's samples count its own transactions, not the face's others
    assert metric_value(found, "mbgw_requests", "mbgw_requests_total", line="serial") == 1
    assert metric_value(found, "mbgw_replies", "mbgw_replies_total", line="serial") == 1
    assert metric_value(found, "mbgw_device_replies", "mbgw_device_replies_total",
                        line="meters", address=rig.METER) == 2
    assert metric_value(found, "mbgw_device_replies", "mbgw_device_replies_total",
                        line="serial", address=rig.SERIAL_SLAVE) == 1
    assert metric_value(found, "mbgw_transaction_latency_seconds",
                        "mbgw_transaction_latency_seconds_count",
                        line="meters", address=rig.METER) == 2


def test_each_line_counts_its_own_transactions_and_the_daemon_all(two_lines, client):
    """Line serial's row counts only what went on line serial, meters' what went on
    meters, the daemon's counters every request of the face (an unroutable one too)."""
    gw, serial, meters, port = two_lines
    c = client(gw)
    for address in (0, 1):
        assert c.ask(rig.SERIAL_SLAVE, read_holding(address, 1)) == rig.hr_reply(address, 1)
    for address in (0, 1, 2):
        assert c.ask(rig.METER_UNIT, read_holding(address, 1)) == rig.hr_reply(address, 1)
    assert len(rig.received(serial.record)) == 2
    assert len(rig.received(meters.record)) == 3

    def booked():
        """The books are kept after a reply has gone (C forwards it first)."""
        s = status(gw)
        rows = {row["name"]: row["replies"] for row in s["lines"]}
        return s if (s["counters"]["replies"] >= 5 and rows["serial"] >= 2
                     and rows["meters"] >= 3) else None

    s = until(booked, "the five transactions booked", 5)
    rows = {row["name"]: row for row in s["lines"]}
    assert (rows["serial"]["requests"], rows["serial"]["replies"]) == (2, 2)
    assert rows["serial"]["counters"]["requests"] == 2
    assert (rows["meters"]["requests"], rows["meters"]["replies"]) == (3, 3)
    assert (s["counters"]["requests"], s["counters"]["replies"]) == (5, 5)

    unrouted = 200          # no route takes it: 0x0A (--exception), counted by the daemon
    assert c.ask(unrouted, read_holding(0, 1)) == bytes((0x83, 0x0A))
    s = status(gw)
    rows = {row["name"]: row for row in s["lines"]}
    assert (rows["serial"]["requests"], rows["serial"]["replies"]) == (2, 2)
    assert rows["serial"]["counters"]["unroutable"] == 0
    assert rows["serial"]["counters"]["gateway_exceptions"] == 0
    assert (s["counters"]["requests"], s["counters"]["replies"]) == (6, 6)
    assert (s["counters"]["unroutable"], s["counters"]["gateway_exceptions"]) == (1, 1)
    assert len(rig.received(serial.record)) == 2 and len(rig.received(meters.record)) == 3
    found = scraped(port)
    assert metric_value(found, "mbgw_requests", "mbgw_requests_total", line="serial") == 2
    assert metric_value(found, "mbgw_requests", "mbgw_requests_total", line="meters") == 3


def test_a_line_in_master_mode_is_shown_and_measured_by_its_name(lines, gateway, tmp_path):
    """A slave-mode daemon with a serial master on line panel reaching line serial's slave:
    panel's row, devices and metric samples, and its trace events named panel."""
    serial = lines("serial", rig.SERIAL_SLAVE)
    (tmp_path / "panel").mkdir()
    panel = PtyPair(tmp_path / "panel")
    port = free_port()
    try:
        # a line in master mode takes no stout: written here, not by the rig's lines_toml
        (tmp_path / "mbgw.toml").write_text(
            f'[[line]]\nname = "panel"\ndevice = "{panel.gateway}"\nmode = "master"\n'
            f'baudrate = 19200\n')
        gw = gateway(serial, {"routes": [{"units": "1-2", "from": "panel", "line": "serial",
                                          "address": rig.SERIAL_SLAVE}]},
                     "--metrics", f"127.0.0.1:{port}")
        only_panel = TraceStream(gw, line="panel")
        master = os.open(panel.device, os.O_RDWR | os.O_NOCTTY)
        try:
            request = bytes((1,)) + read_holding(0, 1)
            os.write(master, rtu_frame(request))
            expected = rtu_frame(bytes((1,)) + rig.hr_reply(0, 1))
            assert read_pty(master, len(expected)) == expected
            asked, answered = only_panel.events(2)
        finally:
            os.close(master)
            only_panel.close()
        assert (asked["line"], asked["address"], answered["line"], answered["outcome"]) == \
            ("panel", 1, "panel", "reply")
        assert rig.received(serial.record) == [bytes((rig.SERIAL_SLAVE,)) + read_holding(0, 1)]
        rows = {row["name"]: row for row in status(gw)["lines"]}
        assert (rows["panel"]["mode"], rows["panel"]["requests"]) == ("master", 1)
        assert [(d["line"], d["address"]) for d in rows["panel"]["devices"]] == [("panel", 1)]
        found = scraped(port)
        assert metric_value(found, "mbgw_requests", "mbgw_requests_total", line="panel") == 1
        assert metric_value(found, "mbgw_device_transactions",
                            "mbgw_device_transactions_total", line="panel", address=1) == 1
    finally:
        panel.stop()
