"""What an operator sees: `mbgw status [--json]`, `mbgw clients close`, `mbgw stats reset`,
`mbgw trace [--pcap]` and the Prometheus endpoint, against a gateway whose serial line has
the scripted faulty slave of tests/peers/fault_slave.py on it.

Every figure is read the way an operator reads it: `python -m mbgw ...` as a subprocess over
the daemon's control socket, /metrics over HTTP parsed by prometheus_client's parser, the
pcap by Debian's tshark.  Clients are raw sockets with hand-built MBAP frames, each waiting
for its own reply (or, with --exception, the gateway's 0x0B after stout): a reply is the event
that says the transaction is over and counted.
"""
import functools
import json
import os
import pwd
import re
import shutil
import socket
import stat
import subprocess
import tempfile
import time
import urllib.error
import urllib.request

import pytest
from prometheus_client import parser

from mbgw.ops.device_stats import COUNTS, LATENCY_BUCKETS_MS
from tests.harness import free_port, stop_counters
from tests.integration.slave.test_demotion import probed
from tests.modbus import Client, holding_reply, mbap, read_holding, rtu
from tests.ops import (
    devices,
    health_log,
    mbgw,
    metric_families,
    metric_value,
    status,
    tracing,
    tshark_warnings,
    wait_for,
)

pytestmark = pytest.mark.integration

STOUT_MS = 200


@pytest.fixture
def rig(pty_pair, recording_peer, start_gateway):
    """rig(*gateway_options, peer=(...)) -> a ready gateway (stout 200 ms, 38400 bit/s) with
    the fault slave on its line."""
    def start(*options: str, peer=()):
        recording_peer("fault_slave.py", *peer)
        return start_gateway(pty_pair.gateway, "--baudrate", "38400", "--stout", str(STOUT_MS),
                             *options)
    return start


def counts(device: dict) -> dict[str, int]:
    """The device's non-zero counters."""
    return {name: device[name] for name in COUNTS if device[name]}


def peer_of(c: Client) -> str:
    host, port = c.sock.getsockname()[:2]
    return f"{host}:{port}"


def served(c: Client, tid: int, unit: int = 1, start: int = 0, count: int = 1) -> None:
    c.send(mbap(tid, unit, read_holding(start, count)))
    assert c.recv() == (tid, unit, holding_reply(start, count))


# --- counters and health --------------------------------------------------------------------

@pytest.mark.serial
def test_counters_and_health_move_exactly_under_a_faulty_slave(rig, client):
    """One transaction per kind of fault, then the daemon's figures: nothing more, nothing
    less, each on the right device."""
    gw = rig("--exception", peer=("--late-ms", "300", "--garbage-pause-ms", "60"))
    c = client(gw)
    started = time.time()
    served(c, 1, unit=1)                                     # well-behaved
    for tid, unit in ((2, 2), (4, 4), (5, 5), (7, 7)):      # silent, bad CRC, wrong unit,
        c.send(mbap(tid, unit, read_holding(0, 1)))          # wrong function: no valid reply
        assert c.recv() == (tid, unit, b"\x83\x0b")
    c.send(mbap(11, 11, read_holding(0, 1)))                # an exception from the device
    assert c.recv() == (11, 11, b"\x83\x02")
    served(c, 13, unit=13)                                   # garbage, silence, the reply
    served(c, 8, unit=8)                                     # a foreign frame, then the reply
    c.send(mbap(0, 0, b"\x06\x00\x01\x00\x2a"), mbap(1, 1, read_holding(0, 1)))   # broadcast
    assert c.recv() == (1, 1, holding_reply(0, 1))
    c.send(mbap(3, 3, read_holding(0, 1)))                  # answers 100 ms after stout
    assert c.recv() == (3, 3, b"\x83\x0b")
    # the late reply lands on the idle line during unit 3's late window: a late reply
    wait_for(gw, lambda s: s["counters"]["late_replies"] > 0, "counted the late reply")

    s = status(gw)
    expected = dict.fromkeys(s["counters"], 0)
    noise = len(rtu(4, holding_reply(0, 1))) + len(b"\x55\xaa\x55")  # bad CRC, garbage
    expected.update(requests=11, replies=10, device_exceptions=1, gateway_exceptions=5,
                    timeouts=5, crc_errors=1, invalid_frames=1, wrong_unit=2, wrong_function=1,
                    broadcasts=1, late_replies=1, bytes_sent=11 * 8,
                    bytes_received=s["counters"]["bytes_received"], connections_accepted=1,
                    noise_bytes=noise)
    assert s["counters"] == expected
    # at least the frames that were taken
    assert s["counters"]["bytes_received"] >= 2 * 7 + 7 + 5 + 7 + 7

    d = devices(s)
    assert sorted(d) == [0, 1, 2, 3, 4, 5, 7, 8, 11, 13]
    assert {a: counts(d[a]) for a in d} == {
        0: {"transactions": 1, "broadcasts": 1},
        1: {"transactions": 2, "replies": 2},
        2: {"transactions": 1, "timeouts": 1},
        3: {"transactions": 1, "timeouts": 1, "late_replies": 1},
        4: {"transactions": 1, "timeouts": 1, "crc_errors": 1},
        5: {"transactions": 1, "timeouts": 1, "wrong_unit": 1},
        7: {"transactions": 1, "timeouts": 1, "wrong_function": 1},
        8: {"transactions": 1, "replies": 1, "wrong_unit": 1},
        11: {"transactions": 1, "replies": 1},
        13: {"transactions": 1, "replies": 1, "invalid_frames": 1},
    }
    assert {a: (d[a]["exceptions"], d[a]["gateway_exceptions"]) for a in d} == {
        a: ({"0x02": 1} if a == 11 else {}, {"0x0b": 1} if a in (2, 3, 4, 5, 7) else {})
        for a in d}
    now = time.time()
    for a, device in d.items():
        failing = a in (2, 3, 4, 5, 7)
        assert device["health"] == ("degraded" if failing else "up"), a
        assert device["consecutive_failures"] == int(failing)
        if failing or a == 0:
            assert device["last_success"] is None, a
        else:
            assert started <= device["last_success"] <= now
        assert sum(device["latency_buckets_ms"].values()) == device["replies"]
    for a in (2, 3, 4, 5, 7):
        assert health_log(gw, a) == ["degraded"]     # once, for one failure
    assert "is down" not in gw.log()

    # the counters the daemon logs at stop are the same figures
    at_stop = stop_counters(gw)
    assert {k: at_stop[k] for k in s["counters"]} == s["counters"]


def test_bytes_received_counts_every_byte_the_line_carried(rig, client):
    gw = rig("--exception")
    c = client(gw)
    for tid, unit in ((4, 4), (5, 5)):                  # a bad CRC, another address
        c.send(mbap(tid, unit, read_holding(0, 1)))
        assert c.recv() == (tid, unit, b"\x83\x0b")
    assert status(gw)["counters"]["bytes_received"] == 2 * len(rtu(4, holding_reply(0, 1)))


def test_a_device_that_stops_answering_is_down_then_degraded_then_up(rig, client):
    """Address 14 ignores its first three requests: three timeouts make it down; its first
    answer (to a probe) makes it degraded; a window of 20 answers without a failure makes it
    up.  Each change is logged once."""
    # the line probes a down device itself, at the interval: 2 s leaves the reads of its
    # down state below (status, `mbgw status` started as a process) well before the probe
    gw = rig("--exception", "--probe-interval", "2000")
    c = client(gw)
    served(c, 1)
    before = time.time()
    for tid in (1, 2, 3):
        c.send(mbap(tid, 14, read_holding(0, 1)))
        assert c.recv() == (tid, 14, b"\x83\x0b")
        device = devices(status(gw))[14]
        assert device["consecutive_failures"] == tid and device["timeouts"] == tid
        assert device["health"] == ("down" if tid == 3 else "degraded")
        assert device["last_success"] is None
    down = device
    assert before <= down["health_since"] <= time.time()
    assert health_log(gw, 14) == ["degraded", "down"]

    human = mbgw("status", "--control", gw.control)
    assert human.returncode == 0, human.stderr
    row = [row.split() for row in human.stdout.splitlines() if row.split()[:2] == ["14", "down"]]
    assert len(row) == 1, human.stdout
    # FAILS REQUESTS REPLIES TIMEOUTS REFUSED CRC
    assert row[0][2:5] == [row[0][2], "ago", "never"] and row[0][5:11] == ["3", "3", "0", "3",
                                                                          "0", "0"]
    assert row[0][-2:] == ["(gateway", "0x0b:3)"]

    refused = probed(c, 14, read_holding(0, 1), holding_reply(0, 1))
    device = devices(status(gw))[14]
    # two answers: the line's own probe, then the request that found the device back
    assert (device["health"], device["consecutive_failures"], device["replies"]) == \
        ("degraded", 0, 2)
    assert device["demoted_rejects"] == refused
    assert device["gateway_exceptions"] == {"0x0b": 3 + refused}
    assert device["last_success"] >= down["health_since"]
    # 19 answers in all: the failures are still in the window of 20
    c.send(*(mbap(tid, 14, read_holding(0, 1)) for tid in range(5, 22)))
    for tid in range(5, 22):
        assert c.recv() == (tid, 14, holding_reply(0, 1))
    assert devices(status(gw))[14]["health"] == "degraded"
    served(c, 22, unit=14)
    device = devices(status(gw))[14]
    assert (device["health"], device["replies"], device["timeouts"]) == ("up", 20, 3)
    assert health_log(gw, 14) == ["degraded", "down", "degraded", "up"]
    assert health_log(gw, 1) == []


# --- status, clients close, stats reset -----------------------------------------------------

def test_status_lists_every_client_and_device(rig, client):
    gw = rig("--exception")
    clients = [client(gw) for _ in range(3)]
    for i, c in enumerate(clients):
        for n in range(i + 1):
            served(c, 100 * i + n, unit=1)
    clients[2].send(mbap(9, 2, read_holding(0, 1)))
    assert clients[2].recv() == (9, 2, b"\x83\x0b")

    s = status(gw)
    assert s["mode"] == "slave" and s["listening"] == [f"127.0.0.1:{gw.port}"]
    assert s["serial"]["state"] == "up" and s["queue_depth"] == 0
    assert [(c["peer"], c["requests"], c["in_flight"]) for c in s["clients"]] == \
        [(peer_of(clients[0]), 1, 0), (peer_of(clients[1]), 2, 0), (peer_of(clients[2]), 4, 0)]
    assert len({c["id"] for c in s["clients"]}) == 3

    result = mbgw("status", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    text = result.stdout
    assert f"listening  127.0.0.1:{gw.port}" in text
    assert "line up, queue 0" in text
    assert "clients (3)" in text and "devices (2)" in text
    rows = {row.split()[1]: row.split() for row in text.splitlines()
            if re.match(r"\s+\d+\s+127\.0\.0\.1:\d+\s", row)}
    assert set(rows) == {peer_of(c) for c in clients}
    for c, requests in zip(s["clients"], (1, 2, 4), strict=True):
        # ID, PEER, CONNECTED (date time), REQUESTS, IN FLIGHT, LAST ACTIVITY
        row = rows[c["peer"]]
        assert row[0] == str(c["id"]) and row[4:6] == [str(requests), "0"]
        assert row[-1] == "ago"
    device_rows = {row.split()[0]: row.split()[1] for row in text.splitlines()
                   if re.match(r"\s+\d+\s+(up|degraded|down)\s", row)}
    assert device_rows == {"1": "up", "2": "degraded"}
    assert re.search(r"^\s+requests\s+7\b", text, re.M)
    assert re.search(r"\btimeouts\s+1\b", text)

    # a client that goes away leaves the list
    gone = peer_of(clients[0])
    clients[0].close()
    s = wait_for(gw, lambda s: len(s["clients"]) == 2, "dropped the closed client")
    assert gone not in [c["peer"] for c in s["clients"]]


def test_clients_close_closes_that_client_only(rig, client):
    gw = rig()
    a, b = client(gw), client(gw)
    served(a, 1)
    served(b, 2)
    ids = {c["peer"]: c["id"] for c in status(gw)["clients"]}
    a_id = ids[peer_of(a)]

    result = mbgw("clients", "close", str(a_id), "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"client {a_id} closed"
    a.sock.settimeout(3.0)
    assert a.sock.recv(100) == b""                      # EOF, at once
    served(b, 3)                                         # the other one is untouched
    served(b, 4)
    assert [c["peer"] for c in status(gw)["clients"]] == [peer_of(b)]
    assert f"client {peer_of(a)} closed by the operator" in gw.log()

    again = mbgw("clients", "close", str(a_id), "--control", gw.control)
    assert again.returncode == 1 and f"no client {a_id}" in again.stderr
    counters = stop_counters(gw)
    assert (counters["requests"], counters["replies"], counters["connections_accepted"]) == \
        (4, 4, 2)


def test_clients_lists_and_closes_by_address_and_all(rig, client):
    gw = rig()
    a, b, c = client(gw), client(gw), client(gw)
    for tid, each in enumerate((a, b, c), 1):
        served(each, tid)
    listed = mbgw("clients", "--control", gw.control)
    assert listed.returncode == 0, listed.stderr
    assert "clients (3)" in listed.stdout
    assert all(peer_of(each) in listed.stdout for each in (a, b, c))

    closed = mbgw("clients", "close", peer_of(a), "--control", gw.control)
    assert closed.returncode == 0, closed.stderr
    a.sock.settimeout(3.0)
    assert a.sock.recv(100) == b""                      # EOF on the wire
    served(b, 4)
    unknown = mbgw("clients", "close", "192.0.2.1:502", "--control", gw.control)
    assert unknown.returncode == 1 and "no client at 192.0.2.1:502" in unknown.stderr

    everyone = mbgw("clients", "close", "--all", "--control", gw.control)
    assert everyone.returncode == 0, everyone.stderr
    for each in (b, c):
        each.sock.settimeout(3.0)
        assert each.sock.recv(100) == b""
    assert status(gw)["clients"] == []
    neither = mbgw("clients", "close", "--control", gw.control)
    assert neither.returncode == 2 and "give an ID, an ADDRESS or --all" in neither.stderr


def test_stats_shows_the_counters_and_the_line_load(rig, client):
    gw = rig()
    c = client(gw)
    served(c, 1)
    served(c, 2)
    shown = mbgw("stats", "--control", gw.control)
    assert shown.returncode == 0, shown.stderr
    assert re.search(r"\brequests\s+2\b", shown.stdout) and \
        re.search(r"\breplies\s+2\b", shown.stdout), shown.stdout
    assert re.search(r"load [\d.]+ % \(10s\), [\d.]+ % \(1min\), [\d.]+ % on average",
                     shown.stdout), shown.stdout
    figures = json.loads(mbgw("stats", "--json", "--control", gw.control).stdout)
    assert figures["counters"]["requests"] == 2
    assert set(figures["line_load_pct"]) == {"10s", "1min"}
    assert all(0 <= v <= 100 for v in figures["line_load_pct"].values())
    assert 0 <= figures["line_utilisation_pct"] <= 100


def test_stats_reset_zeroes_the_counters_and_is_logged(rig, client):
    gw = rig("--exception")
    c = client(gw)
    served(c, 1)
    c.send(mbap(2, 2, read_holding(0, 1)))
    assert c.recv() == (2, 2, b"\x83\x0b")
    before = status(gw)
    assert before["counters"]["requests"] == 2 and before["counters"]["timeouts"] == 1
    one_ok = devices(before)[1]["last_success"]

    result = mbgw("stats", "reset", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "counters reset"
    after = status(gw)
    assert set(after["counters"].values()) == {0}
    assert after["counters_since"] > before["counters_since"]
    d = devices(after)
    assert counts(d[1]) == {} and counts(d[2]) == {}
    assert d[2]["gateway_exceptions"] == {} and sum(d[1]["latency_buckets_ms"].values()) == 0
    # state, not counts: kept
    assert (d[1]["health"], d[1]["last_success"]) == ("up", one_ok)
    assert (d[2]["health"], d[2]["consecutive_failures"]) == ("degraded", 1)
    assert [c["requests"] for c in after["clients"]] == [2]     # per client: not a counter
    assert re.search(r"INFO mbgw\.control: counters reset by the operator \(uid 0\)", gw.log())

    served(c, 3)
    counters = stop_counters(gw)
    assert (counters["requests"], counters["replies"], counters["timeouts"]) == (1, 1, 0)


@pytest.fixture
def open_directory():
    """A directory every user may traverse (the tests' own are root's alone), so that only
    the socket's own mode stands between another user and the socket."""
    path = tempfile.mkdtemp(prefix="mbgw-control-")
    os.chmod(path, 0o755)
    yield path
    shutil.rmtree(path, ignore_errors=True)


def test_control_socket_is_for_root_and_the_group_only(rig, open_directory):
    if os.geteuid() != 0:
        pytest.skip("needs root, to run the client as another user")
    nobody = pwd.getpwnam("nobody")
    path = os.path.join(open_directory, "mbgw.sock")
    gw = rig("--control", path)
    mode = os.stat(path)
    assert stat.S_ISSOCK(mode.st_mode) and stat.S_IMODE(mode.st_mode) == 0o660
    assert (mode.st_uid, mode.st_gid) == (os.geteuid(), os.getegid())
    assert nobody.pw_gid != mode.st_gid

    for command in (["status"], ["status", "--json"], ["clients", "close", "1"],
                    ["stats", "reset"], ["trace", "--count", "1"]):
        denied = mbgw(*command, "--control", path, user="nobody")
        assert denied.returncode == 1, (command, denied.stdout, denied.stderr)
        assert f"mbgw: permission denied on {path}" in denied.stderr, denied.stderr
        assert denied.stdout == ""
    # a member of the socket's group may (so it is the mode that kept nobody out, not the path)
    member = mbgw("status", "--json", "--control", path, user="nobody",
                  groups=str(mode.st_gid))
    assert member.returncode == 0, member.stderr
    assert json.loads(member.stdout)["pid"] == gw.proc.pid
    root = mbgw("status", "--control", path)
    assert root.returncode == 0 and "slave mode" in root.stdout
    assert "counters reset" not in gw.log()


# --- Prometheus -----------------------------------------------------------------------------

def scrape(port: int, path: str = "/metrics") -> tuple[int, str, str]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
            return r.status, r.headers["Content-Type"], r.read().decode()
    except urllib.error.HTTPError as err:
        return err.code, err.headers["Content-Type"], err.read().decode()


def test_metrics_are_the_status_figures_for_prometheus(rig, client):
    port = free_port()
    gw = rig("--exception", "--metrics", f"127.0.0.1:{port}")
    assert f"metrics on http://127.0.0.1:{port}/metrics" in gw.log()
    c = client(gw)
    for tid in range(3):
        served(c, tid, unit=1, count=tid + 1)
    for tid, unit, reply in ((10, 2, b"\x83\x0b"), (11, 11, b"\x83\x02"), (12, 4, b"\x83\x0b"),
                             (13, 2, b"\x83\x0b")):
        c.send(mbap(tid, unit, read_holding(0, 1)))
        assert c.recv() == (tid, unit, reply)
    served(c, 14, unit=8)

    # status first: the line thread keeps its books just after the reply has gone out, and
    # an operator's `mbgw status` takes longer to start than that (a scrape may not)
    s = status(gw)
    code, content_type, text = scrape(port)
    assert code == 200 and content_type == "text/plain; version=0.0.4; charset=utf-8"
    families = metric_families(parser, text)
    value = functools.partial(metric_value, families)

    for name, n in s["counters"].items():
        assert value(f"mbgw_{name}", f"mbgw_{name}_total") == n, name
    busy = value("mbgw_line_busy_seconds", "mbgw_line_busy_seconds_total")
    assert 2 * STOUT_MS / 1000 < busy < s["uptime_s"] + 1
    assert value("mbgw_queue_depth") == 0
    assert value("mbgw_clients_connected") == len(s["clients"]) == 1
    assert value("mbgw_line_up") == 1

    d = devices(s)
    assert sorted(d) == [1, 2, 4, 8, 11]
    for a, device in d.items():
        for name in COUNTS:
            assert value(f"mbgw_device_{name}", f"mbgw_device_{name}_total",
                         address=a) == device[name], (a, name)
        for state in ("up", "degraded", "down"):
            assert value("mbgw_device_health", address=a, state=state) == \
                (device["health"] == state)
        assert value("mbgw_device_consecutive_failures", address=a) == \
            device["consecutive_failures"]
        if device["last_success"] is None:
            assert not [x for x in families["mbgw_device_last_success_timestamp_seconds"]
                        .samples if x.labels["address"] == str(a)]
        else:
            assert value("mbgw_device_last_success_timestamp_seconds", address=a) == \
                pytest.approx(device["last_success"], abs=0.001)
        hist = "mbgw_transaction_latency_seconds"
        assert value(hist, f"{hist}_count", address=a) == device["replies"]
        assert value(hist, f"{hist}_sum", address=a) == \
            pytest.approx(device["latency_sum_ms"] / 1000, abs=1e-6)
        cumulative = 0
        for bound, n in device["latency_buckets_ms"].items():
            cumulative += n
            le = "+Inf" if bound == "+Inf" else repr(int(bound) / 1000)
            assert value(hist, f"{hist}_bucket", address=a, le=le) == cumulative, (a, le)
        assert len(device["latency_buckets_ms"]) == len(LATENCY_BUCKETS_MS) + 1
        # the timing demotion uses (issue 29): stout, learnt p99, probe timeout
        assert value("mbgw_device_stout_seconds", address=a) == device["stout_ms"] / 1000
        assert value("mbgw_device_probe_timeout_seconds", address=a) == \
            pytest.approx(device["probe_timeout_ms"] / 1000, abs=1e-6)
        p99 = [x.value for x in families["mbgw_device_learnt_p99_seconds"].samples
               if x.labels["address"] == str(a)]
        assert p99 == ([] if device["learnt_p99_ms"] is None else
                       [pytest.approx(device["learnt_p99_ms"] / 1000, abs=1e-6)]), a
    assert value("mbgw_device_timeouts", "mbgw_device_timeouts_total", address=2) == 2
    assert value("mbgw_device_health", address=2, state="degraded") == 1
    exceptions = {(x.labels["address"], x.labels["code"], x.labels["source"]): x.value
                  for x in families["mbgw_device_exception_replies"].samples}
    assert exceptions == {("2", "0x0b", "gateway"): 2, ("4", "0x0b", "gateway"): 1,
                          ("11", "0x02", "device"): 1}

    assert scrape(port, "/")[0] == 404
    assert scrape(port, "/metrics/x")[0] == 404


def test_metrics_address_errors(pty_pair, tmp_path):
    bad = mbgw("slave", "--device", pty_pair.gateway, "--metrics", "localhost")
    assert bad.returncode == 2 and "'--metrics'" in bad.stderr, bad.stderr
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = mbgw("slave", "--device", pty_pair.gateway, "--bind", "127.0.0.1",
                      "--mdbport", str(free_port()), "--control", str(tmp_path / "c.sock"),
                      "--metrics", f"127.0.0.1:{port}")
    assert result.returncode == 1, result.stderr
    assert f"mbgw: --metrics 127.0.0.1:{port}: cannot listen there: Address already in use" \
        in result.stderr


# --- trace ----------------------------------------------------------------------------------

TRACE_LINE = re.compile(r"^(\d\d:\d\d:\d\d\.\d{3}) +(request|reply|no reply) +(\S+) +(\d+) +"
                        r"(\d+) +0x([0-9a-f]{2}) +(\d+)(?:  (\S.*))?$")


def test_trace_shows_the_traffic_and_writes_a_pcap_that_tshark_decodes(rig, client, tmp_path):
    if shutil.which("tshark") is None:
        pytest.fail("tshark is missing (scripts/setup.sh installs it)")
    gw = rig()
    pcap = tmp_path / "trace.pcap"
    with tracing(gw, pcap, count=10) as (trace, header):
        assert header[0].split() == ["TIME", "DIRECTION", "CLIENT", "TID", "UNIT", "FC", "LEN",
                                     "OUTCOME"]
        c = client(gw)
        served(c, 0x1111, unit=1, count=2)
        c.send(mbap(0x2222, 1, b"\x06\x00\x01\x00\x2a"))
        assert c.recv() == (0x2222, 1, b"\x06\x00\x01\x00\x2a")
        c.send(mbap(0x3333, 11, read_holding(0, 1)))
        assert c.recv() == (0x3333, 11, b"\x83\x02")
        c.send(mbap(0x4444, 2, read_holding(0, 1)), mbap(0x5555, 1, b"\x04\x00\x00\x00\x01"))
        assert c.recv() == (0x5555, 1, b"\x04\x02\x03\xe8")
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    me = peer_of(c)
    events = []
    for line in out.decode().splitlines():
        m = TRACE_LINE.match(line)
        assert m, line
        _, direction, peer, tid, unit, fc, length, outcome = m.groups()
        assert peer == me
        events.append((direction, int(tid), int(unit), int(fc, 16), int(length),
                       re.sub(r" [\d.]+ ms$", " ms", outcome or "")))
    assert events == [
        ("request", 0x1111, 1, 0x03, 5, ""), ("reply", 0x1111, 1, 0x03, 6, "reply ms"),
        ("request", 0x2222, 1, 0x06, 5, ""), ("reply", 0x2222, 1, 0x06, 5, "reply ms"),
        ("request", 0x3333, 11, 0x03, 5, ""),
        ("reply", 0x3333, 11, 0x83, 2, "device exception ms"),
        ("request", 0x4444, 2, 0x03, 5, ""), ("request", 0x5555, 1, 0x04, 5, ""),
        ("no reply", 0x4444, 2, 0x03, 0, "timeout ms"), ("reply", 0x5555, 1, 0x04, 4,
                                                         "reply ms"),
    ]

    decoded = subprocess.run(
        ["tshark", "-r", str(pcap), "-d", f"tcp.port=={gw.port},mbtcp",
         "-o", f"mbtcp.tcp.port:{gw.port}", "-T", "fields", "-e", "tcp.srcport",
         "-e", "tcp.dstport", "-e", "mbtcp.trans_id", "-e", "mbtcp.unit_id",
         "-e", "modbus.func_code", "-e", "modbus.exception_code", "-e", "_ws.col.Info"],
        capture_output=True, text=True, timeout=60)
    assert decoded.returncode == 0, decoded.stderr
    client_port, server_port = c.sock.getsockname()[1], gw.port
    rows = [line.split("\t") for line in decoded.stdout.splitlines()]
    q, r = (client_port, server_port), (server_port, client_port)
    assert [(int(s), int(d), int(t), int(u), int(f), e, info.split(":")[0].strip())
            for s, d, t, u, f, e, info in rows] == [
        (*q, 0x1111, 1, 3, "", "Query"), (*r, 0x1111, 1, 3, "", "Response"),
        (*q, 0x2222, 1, 6, "", "Query"), (*r, 0x2222, 1, 6, "", "Response"),
        (*q, 0x3333, 11, 3, "", "Query"), (*r, 0x3333, 11, 3, "2", "Response"),
        (*q, 0x4444, 2, 3, "", "Query"), (*q, 0x5555, 1, 4, "", "Query"),
        (*r, 0x5555, 1, 4, "", "Response"),
    ]
    # no malformed or unreassembled segment anywhere
    expert = tshark_warnings(pcap, gw.port)
    assert expert.returncode == 0 and expert.stdout == "", expert.stdout
    # the daemon noticed the trace end (the client closed its end after 10 events)
    wait_for(gw, lambda s: "trace ended" in gw.log(), "ended the trace")
    assert "trace started (uid 0)" in gw.log()
