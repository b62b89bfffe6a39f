"""What status, trace and /metrics show of a master-mode daemon with two lines in master mode
(issue 24): each face's row with its counters and devices, `status --line`, trace events
named by line and narrowed by `--line`, and per-line metric samples.

Peers that are not ours: pymodbus TCP servers behind the routes, raw RTU masters on socat
ptys (checked byte for byte); the trace is read from the control socket as `mbgw trace` reads
it, the metrics over HTTP with prometheus_client's parser.  The rig is test_serial_faces.py's.
"""
import json

import pytest

from tests.harness import free_port
from tests.integration.lines.test_lines_observed import TraceStream
from tests.integration.master import test_serial_faces as rig
from tests.integration.master.test_master import BAUD, holding_reply, identity
from tests.ops import mbgw, metric_value, scraped, status

pytestmark = pytest.mark.integration

lines_master = rig.lines_master       # the rig's fixtures, used here as they are
meters = rig.meters


def test_each_face_is_shown_traced_and_measured_by_line(lines_master, meters, pty_pair,
                                                         second_pty, open_line):
    port, _ = meters
    metrics_port = free_port()
    gw = lines_master(
        "--mdbport", str(port), "--slaveid", f"1 1 1 0 {rig.METER}",
        "--metrics", f"127.0.0.1:{metrics_port}",
        lines=[{"name": "panel", "device": second_pty.gateway, "baudrate": int(BAUD),
                "mode": "master"}],
        routes=[{"units": [1, 2], "from": "panel", "server": [rig.PANEL_METER, port],
                 "offset": 4}])
    serial, panel = open_line(pty_pair.device), open_line(second_pty.device)
    only_panel = TraceStream(gw, line="panel")
    try:
        assert only_panel.header["lines"] == ["serial", "panel"]
        rig.ask(serial, rig.read(1), holding_reply(1, *identity(rig.METER, 1)))
        rig.ask(panel, rig.read(1), holding_reply(1, *identity(rig.PANEL_METER, 5)))
        request, reply = only_panel.events(2)
    finally:
        only_panel.close()
    assert (request["line"], request["direction"], request["address"], request["unit"]) == \
        ("panel", "request", 1, 5)
    assert (reply["line"], reply["direction"], reply["outcome"]) == ("panel", "reply", "reply")
    assert reply["remote"] == reply["server"] and str(port) in reply["remote"]

    rows = {row["name"]: row for row in status(gw)["lines"]}
    assert [(name, row["mode"], row["requests"]) for name, row in rows.items()] == \
        [("serial", "master", 1), ("panel", "master", 1)]
    assert [(d["line"], d["address"]) for d in rows["panel"]["devices"]] == [("panel", 1)]
    one = mbgw("status", "--line", "panel", "--json", "--control", gw.control)
    assert one.returncode == 0, one.stderr
    narrowed = json.loads(one.stdout)
    assert narrowed["line"]["name"] == "panel"
    assert [(r["face"], r["units"]) for r in narrowed["routes"]] == [("panel", "1-2")]

    found = scraped(metrics_port)
    for line in ("serial", "panel"):
        assert metric_value(found, "mbgw_requests", "mbgw_requests_total", line=line) == 1
        assert metric_value(found, "mbgw_device_transactions",
                            "mbgw_device_transactions_total", line=line, address=1) == 1
