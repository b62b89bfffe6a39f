"""Lines of both modes in either mode's daemon (issue 24): a serial master on `[serial]`
reaches a meter on a [[line]] in slave mode (mbgw the master on that line), its address
rewritten by an offset there and given back as asked; a reload adds a line in master mode
(its serial master then reaches the same meter) and removes it, releasing its device; and
a slave-mode daemon serves a line in master mode it starts with or a reload adds, whose master
then reaches lines in slave mode while the TCP clients keep theirs (line serial too, when the
daemon started with `[serial]` alone); status and /metrics list every line.

Peers that are not ours: a recording pymodbus RTU slave on a socat pty pair (the meter), and
raw RTU frames written by the test as the serial masters, each answer checked byte for byte
(tests/modbus.py's CRC)."""
import json
import os
import signal

import pytest

from tests.harness import free_port
from tests.integration.lines.test_lines import (
    METER,
    METER_UNIT,
    SERIAL_SLAVE,
    Line,
    hr_reply,
    received,
)
from tests.integration.lines.test_lines_observed import TraceStream
from tests.integration.master.test_serial_faces import ask, lines_file, read
from tests.modbus import read_holding
from tests.ops import (
    line_threads,
    mbgw,
    metric_value,
    scraped,
    status,
    wait_for_log,
)

pytestmark = pytest.mark.integration

BAUD = 19200
SERIAL_ROUTE = {"units": list(range(32, 64)), "from": "serial", "line": "meters",
                "offset": -31}


@pytest.fixture
def meters(tmp_path, start_peer):
    """The meter's line: a pty pair and a recording pymodbus slave at address METER."""
    line = Line(tmp_path / "meters", start_peer, METER)
    yield line
    line.stop()


def meters_line(meters) -> dict:
    return {"name": "meters", "device": meters.pair.gateway, "baudrate": BAUD, "stout": 300}


@pytest.fixture
def master_daemon(tmp_path, start_gateway, pty_pair):
    """master_daemon(lines, routes) -> `mbgw master` on pty_pair with these [[line]] and
    [[route]] tables in its configuration file, tmp_path/lines.toml."""
    def start(lines, routes, *options: str):
        config = lines_file(tmp_path / "lines.toml", lines, routes)
        return start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate",
                             str(BAUD), "--exception", *options, mode="master", listen=False)
    return start


def test_a_serial_master_reaches_a_meter_on_a_line_in_slave_mode(
        meters, master_daemon, pty_pair, open_line):
    metrics_port = free_port()
    gw = master_daemon([meters_line(meters)], [SERIAL_ROUTE],
                       "--metrics", f"127.0.0.1:{metrics_port}")
    master = open_line(pty_pair.device)
    on_meters = TraceStream(gw, line="meters")
    try:
        # address 32 is address 1 on meters; the answer carries the address the master asked
        ask(master, read(METER_UNIT, 0, 2), bytes((METER_UNIT,)) + hr_reply(0, 2))
        ask(master, read(METER_UNIT, 5, 1), bytes((METER_UNIT,)) + hr_reply(5, 1))
        # line meters' traffic: line serial's master's requests, which name their face
        assert [(e["line"], e["direction"], e["address"], e["server"])
                for e in on_meters.events(4)] == \
            [("serial", direction, METER_UNIT, "line meters")
             for direction in ("request", "reply") * 2]
    finally:
        on_meters.close()
    assert received(meters.record) == [bytes((METER,)) + read_holding(0, 2),
                                       bytes((METER,)) + read_holding(5, 1)]
    rows = {row["name"]: row for row in status(gw)["lines"]}
    assert (rows["serial"]["mode"], rows["meters"]["mode"]) == ("master", "slave")
    assert rows["meters"]["requests"] == 2 and rows["meters"]["replies"] == 2
    text = mbgw("status", "--control", gw.control)
    assert text.returncode == 0, text.stderr
    assert "meters" in text.stdout and "32-63" in text.stdout and "offset -31" in text.stdout
    for line, mode in (("serial", "master"), ("meters", "slave")):
        one = mbgw("status", "--line", line, "--json", "--control", gw.control)
        assert one.returncode == 0, one.stderr
        narrowed = json.loads(one.stdout)
        assert (narrowed["line"]["name"], narrowed["line"]["mode"]) == (line, mode)
        assert narrowed["line"]["requests"] == 2
        assert [(r["face"], r["target"]) for r in narrowed["routes"]] == \
            [("serial", "line meters")]
    families = scraped(metrics_port)
    for line, mode in (("serial", "master"), ("meters", "slave")):
        for name in ("requests", "replies", "timeouts"):
            assert metric_value(families, f"mbgw_{name}", f"mbgw_{name}_total",
                                line=line) == rows[line][name], (line, name)
        assert metric_value(families, "mbgw_line_up", line=line, mode=mode) == 1


def test_a_reload_adds_and_removes_a_line_in_master_mode(
        tmp_path, meters, master_daemon, pty_pair, second_pty, open_line):
    gw = master_daemon([meters_line(meters)], [SERIAL_ROUTE])
    panel_line = {"name": "panel", "device": second_pty.gateway, "baudrate": BAUD,
                  "mode": "master"}
    config = tmp_path / "lines.toml"
    lines_file(config, [meters_line(meters), panel_line],
               [SERIAL_ROUTE, {"units": [7], "from": "panel", "line": "meters", "address": 1}])
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: lines, routes changed")
    assert "takes a restart" not in gw.log()
    panel = open_line(second_pty.device)
    ask(panel, read(7, 3, 1), bytes((7,)) + hr_reply(3, 1))
    assert [row["name"] for row in status(gw)["lines"]] == ["serial", "panel", "meters"]
    # each line's thread is named after it, line serial's keeps its name of one-line days
    assert line_threads(gw) == ["mbgw-line", "mbgw-meters", "mbgw-panel"]
    lines_file(config, [meters_line(meters)], [SERIAL_ROUTE])
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: lines, routes changed", 2)
    assert [row["name"] for row in status(gw)["lines"]] == ["serial", "meters"]
    assert line_threads(gw) == ["mbgw-line", "mbgw-meters"]
    # the device is released: another program may open it now
    fd = os.open(second_pty.gateway, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    os.close(fd)
    # line serial's master still reaches the meter
    master = open_line(pty_pair.device)
    ask(master, read(METER_UNIT, 0, 1), bytes((METER_UNIT,)) + hr_reply(0, 1))
    assert received(meters.record) == [bytes((METER,)) + read_holding(3, 1),
                                       bytes((METER,)) + read_holding(0, 1)]


def test_a_reload_adds_a_line_in_master_mode_to_a_slave_mode_daemon(
        tmp_path, start_peer, start_gateway, meters, second_pty, open_line, client):
    serial = Line(tmp_path / "serial", start_peer, SERIAL_SLAVE)
    try:
        tcp_routes = [{"units": list(range(1, 32)), "line": "serial"},
                      {"units": list(range(32, 64)), "line": "meters", "offset": -31}]
        config = lines_file(tmp_path / "lines.toml", [meters_line(meters)], tcp_routes)
        gw = start_gateway(serial.pair.gateway, "--config", str(config), "--baudrate",
                           str(BAUD), "--stout", "300")
        c = client(gw)
        assert c.ask(METER_UNIT, read_holding(0, 1)) == hr_reply(0, 1)
        panel_line = {"name": "panel", "device": second_pty.gateway, "baudrate": BAUD,
                      "mode": "master"}
        lines_file(config, [meters_line(meters), panel_line],
                   [*tcp_routes, {"units": [7], "from": "panel", "line": "meters",
                                  "address": 1},
                    {"units": [9], "from": "panel", "line": "serial",
                     "address": SERIAL_SLAVE}])
        os.kill(gw.proc.pid, signal.SIGHUP)
        wait_for_log(gw, "configuration reloaded: lines, routes changed")
        panel = open_line(second_pty.device)
        ask(panel, read(7, 2, 1), bytes((7,)) + hr_reply(2, 1))
        ask(panel, read(9, 4, 1), bytes((9,)) + hr_reply(4, 1))
        assert c.ask(METER_UNIT, read_holding(1, 1)) == hr_reply(1, 1)   # same connection
        rows = {row["name"]: row["mode"] for row in status(gw)["lines"]}
        assert rows == {"serial": "slave", "meters": "slave", "panel": "master"}
        assert received(meters.record) == [bytes((METER,)) + read_holding(0, 1),
                                           bytes((METER,)) + read_holding(2, 1),
                                           bytes((METER,)) + read_holding(1, 1)]
        assert received(serial.record) == [bytes((SERIAL_SLAVE,)) + read_holding(4, 1)]
    finally:
        serial.stop()


def test_a_slave_mode_daemon_started_with_a_line_in_master_mode_serves_it(
        tmp_path, start_peer, start_gateway, meters, second_pty, open_line, client):
    serial = Line(tmp_path / "serial", start_peer, SERIAL_SLAVE)
    try:
        panel_line = {"name": "panel", "device": second_pty.gateway, "baudrate": BAUD,
                      "mode": "master"}
        config = lines_file(tmp_path / "lines.toml", [meters_line(meters), panel_line],
                            [{"units": list(range(1, 32)), "line": "serial"},
                             {"units": [7], "from": "panel", "line": "meters", "address": 1}])
        gw = start_gateway(serial.pair.gateway, "--config", str(config), "--baudrate",
                           str(BAUD), "--stout", "300")
        panel = open_line(second_pty.device)
        streams = {line: TraceStream(gw, line=line) for line in ("panel", "meters")}
        raw_panel = TraceStream(gw, raw=True, line="panel")
        try:
            assert streams["panel"].header["lines"] == ["serial", "meters", "panel"]
            ask(panel, read(7, 2, 1), bytes((7,)) + hr_reply(2, 1))
            # the panel's line as it went: its master's request, mbgw's reply
            assert [(b["line"], b["kind"], bytes.fromhex(b["bytes"])[:-2])
                    for b in raw_panel.events(2)] == \
                [("panel", "request", read(7, 2, 1)),
                 ("panel", "reply", bytes((7,)) + hr_reply(2, 1))]
            for line, stream in streams.items():      # the panel's request, on each
                assert [(e["line"], e["direction"], e["address"], e["server"])
                        for e in stream.events(2)] == [("panel", "request", 7, "line meters"),
                                                       ("panel", "reply", 7, "line meters")], \
                    line
        finally:
            for stream in (*streams.values(), raw_panel):
                stream.close()
        assert client(gw).ask(SERIAL_SLAVE, read_holding(0, 1)) == hr_reply(0, 1)
        rows = {row["name"]: row for row in status(gw)["lines"]}
        assert rows["panel"]["mode"] == "master" and rows["panel"]["requests"] == 1
        for line, mode in (("panel", "master"), ("meters", "slave")):
            text = mbgw("status", "--line", line, "--control", gw.control)
            assert text.returncode == 0, text.stderr
            assert f"devices of line {line} (1)" in text.stdout, text.stdout
            assert f"({mode})" in text.stdout and "panel   7" in text.stdout, text.stdout
        assert line_threads(gw) == ["mbgw-line", "mbgw-meters", "mbgw-panel"]
        assert received(meters.record) == [bytes((METER,)) + read_holding(2, 1)]
    finally:
        serial.stop()


def test_a_reload_adds_a_serial_face_to_a_daemon_started_with_serial_alone(
        tmp_path, start_peer, start_gateway, second_pty, open_line, client):
    serial = Line(tmp_path / "serial", start_peer, SERIAL_SLAVE)
    try:
        config = lines_file(tmp_path / "lines.toml", [], [])
        gw = start_gateway(serial.pair.gateway, "--config", str(config), "--baudrate",
                           str(BAUD), "--stout", "300")
        c = client(gw)
        assert c.ask(SERIAL_SLAVE, read_holding(0, 1)) == hr_reply(0, 1)
        panel_line = {"name": "panel", "device": second_pty.gateway, "baudrate": BAUD,
                      "mode": "master"}
        lines_file(config, [panel_line], [{"units": [9], "from": "panel", "line": "serial",
                                           "address": SERIAL_SLAVE}])
        os.kill(gw.proc.pid, signal.SIGHUP)
        wait_for_log(gw, "configuration reloaded: lines, routes changed")
        panel = open_line(second_pty.device)
        ask(panel, read(9, 4, 1), bytes((9,)) + hr_reply(4, 1))
        assert c.ask(SERIAL_SLAVE, read_holding(1, 1)) == hr_reply(1, 1)   # same connection
        assert received(serial.record) == [bytes((SERIAL_SLAVE,)) + read_holding(0, 1),
                                           bytes((SERIAL_SLAVE,)) + read_holding(4, 1),
                                           bytes((SERIAL_SLAVE,)) + read_holding(1, 1)]
    finally:
        serial.stop()
