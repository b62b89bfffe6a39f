"""Master mode's operator tools: `mbgw status [--json]`, `mbgw stats reset`, `mbgw trace
[--pcap]`, /metrics and the health log, against `mbgw master` with a serial master on the
pty (raw RTU frames written by the test) and pymodbus Modbus TCP servers on loopback: one
that answers, one that accepts connections and never answers, one address where nobody
listens.  Each request's answer on the line is the event that says it is over; what the
daemon does after writing it (counting the reply) is waited for on its own status."""
import functools
import os
import re
import shutil
import subprocess
import time
import urllib.request

import pytest
from prometheus_client import parser

from mbgw.ops.device_stats import LATENCY_BUCKETS_MS, MASTER_COUNTS
from tests.harness import free_port
from tests.integration.master.rig import (
    ask,
    holding_reply,
    identity,
    mbgw,
    probed,
    read_holding,
    read_pty,
    rtu,
    status,
    stop_counters,
    unanswered,
    wait_for,
)
from tests.integration.ops.test_trace_raw import GARBAGE, Trace, bursts
from tests.ops import devices, health_log, metric_families, metric_value, tracing, tshark_warnings

pytestmark = pytest.mark.integration

SERVER = "127.0.6.1"          # answers; units 1..40 and 255
SILENT = "127.0.6.2"          # accepts connections, never answers
ABSENT = "127.0.6.9"          # nobody listens: connection refused
TCPTO_MS = 250
OTHER = 50                    # an address outside the table
# addresses 1, 2 -> SERVER units 1, 2; 3 -> SILENT; 4 -> ABSENT
TABLE = ("1 2 1 0 " + SERVER, "3 3 1 0 " + SILENT, "4 4 1 0 " + ABSENT)
BROADCAST_WRITE = bytes.fromhex("00 06 0005 002a")     # register 5 := 42, every server


def exception(address: int, code: int) -> bytes:
    return bytes((address, 0x83, code))


def reply(address: int, host: str, unit: int) -> bytes:
    return holding_reply(address, *identity(host, unit))


@pytest.fixture
def rig(servers_at, start_master):
    """rig(*options) -> a ready gateway with TABLE, tcpto TCPTO_MS and exception on."""
    def start(*options: str):
        port, _ = servers_at(SERVER, silent=[SILENT])
        args = [a for entry in TABLE for a in ("--slaveid", entry)]
        return start_master("--mdbport", str(port), "--tcpto", str(TCPTO_MS), "--exception",
                            *args, *options), port
    return start


def every_outcome(gw, fd: int) -> dict:
    """One request per outcome (8 frames from the master): replies, a server's exception, a
    timeout, an unreachable server, an address outside the table, a broadcast; the daemon's
    status once it has counted them all."""
    ask(fd, read_holding(1), expected=reply(1, SERVER, 1))
    ask(fd, read_holding(1), expected=reply(1, SERVER, 1))
    ask(fd, read_holding(2, start=10, count=1), expected=exception(2, 0x02))
    ask(fd, read_holding(3), expected=exception(3, 0x0B))
    ask(fd, read_holding(4), expected=exception(4, 0x0A))
    unanswered(fd, read_holding(OTHER), then=read_holding(2), expected=reply(2, SERVER, 2))
    # Last, and alone: it gets no answer, and pymodbus's server loses a request that reaches
    # it in the same read as the broadcast (a real master pauses after a broadcast first).
    os.write(fd, rtu(BROADCAST_WRITE))
    return wait_for(gw, lambda s: s["counters"]["broadcasts"] == 1 and
                    s["counters"]["replies"] == 6, "counted the broadcast and the replies")


def counts(device: dict) -> dict[str, int]:
    return {name: device[name] for name in MASTER_COUNTS if device[name]}


# --- status ---------------------------------------------------------------------------------

def test_status_figures_match_the_traffic(rig, line):
    gw, port = rig()
    started = time.time()
    every_outcome(gw, line)

    s = status(gw)
    assert s["mode"] == "master" and s["pid"] == gw.proc.pid
    assert s["serial"]["state"] == "up" and s["serial"]["baudrate"] == 19200
    assert s["upstream"] | {"connections": None} == {
        "port": port, "tcpto_ms": TCPTO_MS, "exception": True, "max_connections": 5,
        "connections": None}
    assert [r["route"] for r in s["slaveid"]] == [
        f"1..2 -> {SERVER} unit 1..2", f"3..3 -> {SILENT} unit 1", f"4..4 -> {ABSENT} unit 1"]
    assert s["counters"] == {
        "requests": 6, "replies": 6, "device_exceptions": 1, "gateway_exceptions": 2,
        "timeouts": 1, "unreachable": 1, "demoted_rejects": 0, "broadcasts": 1, "crc_errors": 0,
        "invalid_frames": 0, "other_addresses": 1, "late_replies": 0, "wrong_unit": 0,
        "wrong_function": 0, "abandoned": 0, "connections_opened": 2, "connections_evicted": 0,
        "connections_lost": 0, "connections_bad_header": 0}

    connections = {c["server"]: c for c in s["upstream"]["connections"]}
    assert set(connections) == {f"{SERVER}:{port}", f"{SILENT}:{port}"}
    served, mute = connections[f"{SERVER}:{port}"], connections[f"{SILENT}:{port}"]
    assert (served["requests"], served["units"]) == (5, [0, 1, 2])     # broadcast: unit 0
    assert (mute["requests"], mute["units"]) == (2, [0, 1])
    assert started <= served["connected_since"] <= time.time()
    assert re.fullmatch(r"127\.0\.0\.1:\d+", served["local"])

    d = devices(s)
    assert sorted(d) == [0, 1, 2, 3, 4]
    assert {a: counts(d[a]) for a in d} == {
        0: {"transactions": 1, "broadcasts": 1},
        1: {"transactions": 2, "replies": 2},
        2: {"transactions": 2, "replies": 2},
        3: {"transactions": 1, "timeouts": 1},
        4: {"transactions": 1, "unreachable": 1},
    }
    assert {a: (d[a]["exceptions"], d[a]["gateway_exceptions"]) for a in d} == {
        0: ({}, {}), 1: ({}, {}), 2: ({"0x02": 1}, {}), 3: ({}, {"0x0b": 1}),
        4: ({}, {"0x0a": 1})}
    assert {a: d[a].get("upstream") for a in d} == {
        0: None, 1: {"host": SERVER, "unit": 1}, 2: {"host": SERVER, "unit": 2},
        3: {"host": SILENT, "unit": 1}, 4: {"host": ABSENT, "unit": 1}}
    assert {a: (d[a]["health"], d[a]["consecutive_failures"]) for a in d} == {
        0: ("up", 0), 1: ("up", 0), 2: ("up", 0), 3: ("degraded", 1), 4: ("degraded", 1)}
    for a in (1, 2):
        assert started <= d[a]["last_success"] <= time.time()
        assert sum(d[a]["latency_buckets_ms"].values()) == d[a]["replies"]
    assert d[3]["last_success"] is None and d[4]["last_success"] is None

    # the same, for a human
    human = mbgw("status", "--control", gw.control)
    assert human.returncode == 0, human.stderr
    text = human.stdout
    assert ", master mode, pid " in text.splitlines()[0]
    assert f"servers    port {port}, tcpto {TCPTO_MS} ms, exception on, at most 5 " \
           f"connections" in text
    assert f"slaveid    1..2 -> {SERVER} unit 1..2" in text
    assert "upstream connections (2)" in text and "devices (5)" in text
    rows = {row.split()[0]: row.split() for row in text.splitlines()
            if re.match(r"\s+\d+\s+(up|degraded|down)\s", row)}
    # ADDR HEALTH SINCE(2) LAST-SUCCESS(1|2) FAILS REQUESTS REPLIES TIMEOUTS REFUSED UNREACH
    # INVALID ABANDON SERVER UNIT EXCEPTIONS...
    assert rows["3"][1:] == ["degraded", rows["3"][2], "ago", "never", "1", "1", "0", "1",
                             "0", "0", "0", "0", SILENT, "1", "(gateway", "0x0b:1)"]
    assert rows["2"][-3:] == [SERVER, "2", "0x02:1"]
    assert re.search(r"^\s+127\.0\.6\.1:\d+\s+127\.0\.0\.1:\d+\s+\S+ \S+\s+5\s+0,1,2\s", text,
                     re.M), text
    assert re.search(r"\bunreachable\s+1\b", text) and re.search(r"\babandoned\s+0\b", text)

    # the counters logged at stop are the same figures
    assert stop_counters(gw) == s["counters"]


def test_clients_close_says_master_mode_has_none_while_the_table_is_off(rig):
    gw, _ = rig()
    result = mbgw("clients", "close", "1", "--control", gw.control)
    assert result.returncode == 1 and result.stdout == ""
    assert "mbgw: clients close: master mode's only Modbus TCP clients are the exchange " \
        "table's, and the table is off" in result.stderr, result.stderr
    assert "the exchange table is off" in mbgw("clients", "--control", gw.control).stdout


def test_stats_reset_zeroes_the_counters_and_keeps_the_state(rig, line):
    gw, _ = rig()
    ask(line, read_holding(1), expected=reply(1, SERVER, 1))
    ask(line, read_holding(3), expected=exception(3, 0x0B))
    before = wait_for(gw, lambda s: s["counters"]["replies"] == 2, "counted the reply")
    result = mbgw("stats", "reset", "--control", gw.control)
    assert result.returncode == 0 and result.stdout.strip() == "counters reset", result.stderr

    after = status(gw)
    assert set(after["counters"].values()) == {0}
    assert after["counters_since"] > before["counters_since"]
    d = devices(after)
    assert counts(d[1]) == {} and counts(d[3]) == {}
    assert d[3]["gateway_exceptions"] == {} and sum(d[1]["latency_buckets_ms"].values()) == 0
    # state, not counts: kept
    assert d[1]["last_success"] == devices(before)[1]["last_success"]
    assert (d[3]["health"], d[3]["consecutive_failures"]) == ("degraded", 1)
    assert sorted(c["requests"] for c in after["upstream"]["connections"]) == [1, 1]
    assert re.search(r"INFO mbgw\.control: counters reset by the operator \(uid \d+\)",
                     gw.log())

    ask(line, read_holding(2), expected=reply(2, SERVER, 2))
    counters = stop_counters(gw)
    assert (counters["requests"], counters["replies"], counters["timeouts"]) == (1, 1, 0)


# --- health ---------------------------------------------------------------------------------

def test_a_silent_server_takes_its_address_down_and_a_recovery_brings_it_up(
        servers_at, start_master, line):
    """Address 5's server accepts connections and never answers: three tcpto in a row make
    the address down.  The server is replaced by one that answers (same address and port):
    the first probe's reply makes it degraded, 20 in a row up.  Each change is logged once."""
    host = "127.0.6.5"
    port, mute = servers_at(silent=[host])
    gw = start_master("--mdbport", str(port), "--tcpto", str(TCPTO_MS), "--exception",
                      "--slaveid", f"5 5 3 0 {host}", "--probe-interval", "100")
    for n in (1, 2, 3):
        ask(line, read_holding(5), expected=exception(5, 0x0B))
        device = devices(status(gw))[5]
        assert (device["timeouts"], device["consecutive_failures"]) == (n, n)
        assert device["health"] == ("down" if n == 3 else "degraded")
    assert device["last_success"] is None
    assert health_log(gw, 5) == ["degraded", "down"]
    assert f"device 5 is down: 3 requests in a row without a valid reply (server {host} " \
           f"unit 3)" in gw.log()

    mute.stop()
    servers_at(host, port=port)
    refused = probed(line, read_holding(5), reply(5, host, 3), exception(5, 0x0B))
    device = devices(status(gw))[5]
    assert (device["health"], device["consecutive_failures"], device["replies"]) == (
        "degraded", 0, 1)
    assert device["demoted_rejects"] == refused
    for _ in range(18):
        ask(line, read_holding(5), expected=reply(5, host, 3))
    assert devices(status(gw))[5]["health"] == "degraded"     # 3 failures in the last 20
    ask(line, read_holding(5), expected=reply(5, host, 3))
    device = devices(status(gw))[5]
    assert (device["health"], device["replies"], device["timeouts"]) == ("up", 20, 3)
    assert health_log(gw, 5) == ["degraded", "down", "degraded", "up"]
    counters = stop_counters(gw)
    assert (counters["connections_opened"], counters["connections_lost"]) == (2, 1)


# --- trace ----------------------------------------------------------------------------------

TRACE_LINE = re.compile(r"^(\d\d:\d\d:\d\d\.\d{3}) +(request|reply|no reply|ignored) +(\d+) +"
                        r"(\S+) +(\d+|-) +(\d+|-) +0x([0-9a-f]{2}) +(\d+)(?:  (\S.*))?$")


def test_trace_shows_both_sides_and_writes_a_pcap_that_tshark_decodes(rig, line, tmp_path):
    if shutil.which("tshark") is None:
        pytest.fail("tshark is missing (scripts/setup.sh installs it)")
    gw, port = rig()
    pcap = tmp_path / "trace.pcap"
    with tracing(gw, pcap, count=15) as (trace, header):
        assert header[0].split() == ["TIME", "DIRECTION", "ADDR", "SERVER", "TID", "UNIT",
                                     "FC", "LEN", "OUTCOME"]
        every_outcome(gw, line)
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    events = []
    for text in out.decode().splitlines():
        m = TRACE_LINE.match(text)
        assert m, text
        _, direction, address, server, tid, unit, fc, length, outcome = m.groups()
        events.append((direction, int(address), server, tid, unit, int(fc, 16), int(length),
                       re.sub(r" [\d.]+ ms$", " ms", outcome or "")))
    ok, mute, gone = (f"{h}:{port}" for h in (SERVER, SILENT, ABSENT))
    assert events == [
        ("request", 1, ok, "1", "1", 0x03, 5, ""), ("reply", 1, ok, "1", "1", 0x03, 8,
                                                    "reply ms"),
        ("request", 1, ok, "2", "1", 0x03, 5, ""), ("reply", 1, ok, "2", "1", 0x03, 8,
                                                    "reply ms"),
        ("request", 2, ok, "3", "2", 0x03, 5, ""),
        ("reply", 2, ok, "3", "2", 0x83, 2, "server exception ms"),
        ("request", 3, mute, "1", "1", 0x03, 5, ""),
        ("no reply", 3, mute, "1", "1", 0x03, 0, "timeout, answered 0x0b"),
        ("no reply", 4, gone, "-", "1", 0x03, 0, "unreachable, answered 0x0a"),
        ("ignored", OTHER, "-", "-", "-", 0x03, 5, "not in the slaveid table"),
        ("request", 2, ok, "4", "2", 0x03, 5, ""), ("reply", 2, ok, "4", "2", 0x03, 8,
                                                    "reply ms"),
        ("request", 0, ok, "5", "0", 0x06, 5, ""), ("request", 0, mute, "2", "0", 0x06, 5, ""),
        ("no reply", 0, "-", "-", "0", 0x06, 0, "broadcast: 2 of 3 servers"),
    ]

    decoded = subprocess.run(
        ["tshark", "-r", str(pcap), "-d", f"tcp.port=={port},mbtcp",
         "-o", f"mbtcp.tcp.port:{port}", "-T", "fields", "-e", "ip.dst", "-e", "tcp.dstport",
         "-e", "mbtcp.trans_id", "-e", "mbtcp.unit_id", "-e", "modbus.func_code",
         "-e", "modbus.exception_code", "-e", "_ws.col.Info"],
        capture_output=True, text=True, timeout=60)
    assert decoded.returncode == 0, decoded.stderr
    rows = [(f"{dst}:{dport}", int(t), int(u), int(f), e, info.split(":")[0].strip())
            for dst, dport, t, u, f, e, info in
            (line.split("\t") for line in decoded.stdout.splitlines())]
    to_us = [r for r in rows if r[-1] == "Response"]
    assert all(re.fullmatch(r"127\.0\.0\.1:\d+", r[0]) for r in to_us), rows
    assert [r if r[-1] == "Query" else ("mbgw",) + r[1:] for r in rows] == [
        (ok, 1, 1, 3, "", "Query"), ("mbgw", 1, 1, 3, "", "Response"),
        (ok, 2, 1, 3, "", "Query"), ("mbgw", 2, 1, 3, "", "Response"),
        (ok, 3, 2, 3, "", "Query"), ("mbgw", 3, 2, 3, "2", "Response"),
        (mute, 1, 1, 3, "", "Query"),
        (ok, 4, 2, 3, "", "Query"), ("mbgw", 4, 2, 3, "", "Response"),
        (ok, 5, 0, 6, "", "Query"), (mute, 2, 0, 6, "", "Query"),
    ]
    expert = tshark_warnings(pcap, port)
    assert expert.returncode == 0 and expert.stdout == "", expert.stdout
    wait_for(gw, lambda s: "trace ended" in gw.log(), "ended the trace")


# --- Prometheus -----------------------------------------------------------------------------

def test_metrics_are_the_status_figures_for_prometheus(rig, line):
    metrics_port = free_port()
    gw, _ = rig("--metrics", f"127.0.0.1:{metrics_port}")
    assert f"metrics on http://127.0.0.1:{metrics_port}/metrics" in gw.log()
    every_outcome(gw, line)

    with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=5) as r:
        assert r.status == 200
        text = r.read().decode()
    s = status(gw)
    families = metric_families(parser, text)
    value = functools.partial(metric_value, families)

    assert value("mbgw_info", mode="master") == 1
    assert set(s["counters"]) >= {"unreachable", "other_addresses", "abandoned"}
    for name, n in s["counters"].items():
        assert value(f"mbgw_{name}", f"mbgw_{name}_total") == n, name
    assert "mbgw_queue_depth" not in families and "mbgw_clients_connected" not in families
    assert value("mbgw_line_up") == 1
    assert value("mbgw_upstream_connections") == len(s["upstream"]["connections"]) == 2
    assert "mbgw_device_crc_errors" not in families          # slave mode's per-device counts

    for a, device in devices(s).items():
        for name in MASTER_COUNTS:
            assert value(f"mbgw_device_{name}", f"mbgw_device_{name}_total",
                         address=a) == device[name], (a, name)
        for state in ("up", "degraded", "down"):
            assert value("mbgw_device_health", address=a, state=state) == \
                (device["health"] == state)
        hist = "mbgw_transaction_latency_seconds"
        assert value(hist, f"{hist}_count", address=a) == device["replies"]
        assert value(hist, f"{hist}_sum", address=a) == \
            pytest.approx(device["latency_sum_ms"] / 1000, abs=1e-6)
        assert len(device["latency_buckets_ms"]) == len(LATENCY_BUCKETS_MS) + 1
    exceptions = {(x.labels["address"], x.labels["code"], x.labels["source"]): x.value
                  for x in families["mbgw_device_exception_replies"].samples}
    assert exceptions == {("2", "0x02", "device"): 1, ("3", "0x0b", "gateway"): 1,
                          ("4", "0x0a", "gateway"): 1}
    assert value("mbgw_device_unreachable", "mbgw_device_unreachable_total", address=4) == 1


def test_trace_raw_shows_the_masters_requests_our_replies_and_noise(rig, line):
    """Master mode's raw line: what the serial master wrote (a request, then garbage) and
    what mbgw answered, byte for byte as the test wrote and read them on the pty."""
    gw, _ = rig()
    trace = Trace(gw, "--raw")
    try:
        request = read_holding(1)
        ask(line, request, expected=reply(1, SERVER, 1))
        # garbage (a master at the wrong baud rate), the request right behind it: one burst,
        # no valid frame as a whole, though mbgw finds the request at its end and answers
        os.write(line, GARBAGE + rtu(request))
        assert read_pty(line, len(rtu(reply(1, SERVER, 1)))) == rtu(reply(1, SERVER, 1))
        shown = [(kind, data) for _, kind, data in bursts(trace.lines(5))]
    finally:
        trace.stop()
    assert shown == [("request", rtu(request)), ("reply", rtu(reply(1, SERVER, 1))),
                     ("noise", GARBAGE + rtu(request)),
                     ("reply", rtu(reply(1, SERVER, 1)))], shown
