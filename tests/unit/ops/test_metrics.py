"""The Prometheus endpoint (mbgw.ops.metrics): the --metrics address, the exposition text read by
prometheus_client's own parser, and the HTTP server's behaviour with odd clients."""
import errno
import gzip
import math
import socket
import threading
from types import SimpleNamespace

import prometheus_client
import pytest
from prometheus_client import parser
from prometheus_client.core import CounterMetricFamily
from prometheus_client.openmetrics import parser as openmetrics_parser

from mbgw.errors import ConfigError
from mbgw.net.address import parse_host_port
from mbgw.ops.counters import MASTER_NAMES, NAMES, Counters, MasterCounters
from mbgw.ops.device_stats import MASTER_COUNTS, DeviceHealth, HealthRule
from mbgw.ops.metrics import master_collector, slave_collector
from mbgw.ops.metrics_server import MetricsServer
from tests.harness import free_port


@pytest.mark.parametrize("text, expected", [
    ("127.0.0.1:9502", ("127.0.0.1", 9502)),
    ("0.0.0.0:1", ("0.0.0.0", 1)),
    ("[::1]:9502", ("::1", 9502)),
    ("[::]:65535", ("::", 65535)),
    ("localhost:9502", ("localhost", 9502)),
    (":9502", (None, 9502)),
])
def test_metrics_address(text, expected):
    assert parse_host_port(text, "metrics") == expected


@pytest.mark.parametrize("text", ["9502", "127.0.0.1", "127.0.0.1:", "127.0.0.1:0",
                                  "127.0.0.1:65536", "127.0.0.1:http", "::1:9502",
                                  "127.0.0.1:-1"])
def test_bad_metrics_address(text):
    with pytest.raises(ConfigError, match="metrics"):
        parse_host_port(text, "metrics")


def exposition(collector) -> str:
    """The text prometheus_client serves for collector."""
    registry = prometheus_client.CollectorRegistry()
    registry.register(collector)
    return prometheus_client.generate_latest(registry).decode()


def render(*objects) -> str:
    return exposition(slave_collector(*objects))


def render_master(*objects) -> str:
    return exposition(master_collector(*objects))


def live_objects():
    counters = Counters()
    for i, name in enumerate(NAMES):
        setattr(counters, name, i + 1)
    counters.line_busy_ns = 2_500_000_000
    devices = DeviceHealth()
    one = devices.get(1)
    one.transactions = 5
    for ms in (1.0, 3.0, 3.0, 700.0):
        one.answered(ms, None)
    one.failed()
    one.timeouts = 1
    two = devices.get(2)
    two.transactions = 3
    for _ in range(3):
        two.failed()
    two.timeouts = 3
    two.gateway_exception(0x0B)
    two.gateway_exception(0x0B)
    eleven = devices.get(11)
    eleven.transactions = 1
    eleven.answered(6000.0, 0x02)
    return SimpleNamespace(
        counters=counters, devices=devices, scheduler=SimpleNamespace(depth=4),
        server=SimpleNamespace(clients=[object(), object()]), worker=SimpleNamespace(up=True))


def families(text: str) -> dict:
    return {f.name: f for f in parser.text_string_to_metric_families(text)}


def samples(family, **labels) -> dict:
    """{(sample name, frozenset(labels - given)): value} of the samples matching labels
    (line serial's unless a line is given: every per-line family has the label)."""
    labels.setdefault("line", "serial")
    if labels["line"] is None:             # every line's
        del labels["line"]
    return {(s.name, tuple(sorted((k, v) for k, v in s.labels.items() if k not in labels))):
            s.value for s in family.samples
            if all(s.labels.get(k) == v for k, v in labels.items())}


def test_every_counter_and_gauge_is_there_with_help_and_type():
    o = live_objects()
    text = render(o.counters, o.devices, o.scheduler, o.server, o.worker, 1234.5)
    found = families(text)
    for name in NAMES:
        if name == "line_busy_ns":
            continue
        f = found[f"mbgw_{name}"]
        assert f.type == "counter" and f.documentation
        assert [(s.name, s.value) for s in f.samples] == \
            [(f"mbgw_{name}_total", getattr(o.counters, name))]
    busy = found["mbgw_line_busy_seconds"]
    assert busy.type == "counter" and busy.samples[0].value == 2.5
    assert found["mbgw_queue_depth"].samples[0].value == 4
    assert found["mbgw_clients_connected"].samples[0].value == 2
    assert found["mbgw_line_up"].samples[0].value == 1
    assert found["mbgw_start_time_seconds"].samples[0].value == 1234.5
    for f in found.values():
        assert f.documentation, f.name
        assert f.type in ("counter", "gauge", "histogram"), f.name
    # every metric family is declared once, before its samples
    lines = text.splitlines()
    types = [row.split()[2] for row in lines if row.startswith("# TYPE ")]
    assert len(types) == len(set(types))
    assert text.endswith("\n")


def test_every_line_has_its_figures_once_labelled_by_its_name():
    o = live_objects()
    meters = Counters()
    meters.requests, meters.timeouts = 3, 3
    collector = slave_collector(
        o.counters, o.devices, o.scheduler, o.server, o.worker, 0.0,
        lines=lambda: [("serial", o.counters, o.devices), ("meters", meters, DeviceHealth())])
    collector.lines = lambda: [
        {"name": "serial", "device": "/dev/ttyS0", "mode": "slave", "state": "up"},
        {"name": "meters", "device": "/dev/ttyS1", "mode": "slave", "state": "down"},
        {"name": "panel", "device": "/dev/ttyS2", "mode": "master", "state": "up"}]
    found = families(exposition(collector))
    assert samples(found["mbgw_requests"], line=None) == {
        ("mbgw_requests_total", (("line", "serial"),)): o.counters.requests,
        ("mbgw_requests_total", (("line", "meters"),)): 3}
    assert samples(found["mbgw_timeouts"], line="meters") == {("mbgw_timeouts_total", ()): 3}
    assert samples(found["mbgw_line_up"], line=None) == {
        ("mbgw_line_up", (("line", "serial"), ("mode", "slave"))): 1,
        ("mbgw_line_up", (("line", "meters"), ("mode", "slave"))): 0,
        ("mbgw_line_up", (("line", "panel"), ("mode", "master"))): 1}
    # the figures are the counters' families alone, not again under other names
    assert not {"mbgw_line_requests", "mbgw_line_replies", "mbgw_line_timeouts",
                "mbgw_line_open"} & set(found)


def test_per_address_counters_health_and_exceptions():
    o = live_objects()
    found = families(render(o.counters, o.devices, o.scheduler, o.server, o.worker, 0.0))
    timeouts = found["mbgw_device_timeouts"]
    assert samples(timeouts) == {("mbgw_device_timeouts_total", (("address", "1"),)): 1,
                                 ("mbgw_device_timeouts_total", (("address", "2"),)): 3,
                                 ("mbgw_device_timeouts_total", (("address", "11"),)): 0}
    assert samples(found["mbgw_device_replies"], address="1") == \
        {("mbgw_device_replies_total", ()): 4}
    exceptions = found["mbgw_device_exception_replies"]
    assert exceptions.type == "counter"
    assert sorted((s.labels["address"], s.labels["code"], s.labels["source"], s.value)
                  for s in exceptions.samples) == [("11", "0x02", "device", 1),
                                                   ("2", "0x0b", "gateway", 2)]
    health = found["mbgw_device_health"]
    assert {(s.labels["address"], s.labels["state"]): s.value for s in health.samples} == {
        ("1", "up"): 0, ("1", "degraded"): 1, ("1", "down"): 0,
        ("2", "up"): 0, ("2", "degraded"): 0, ("2", "down"): 1,
        ("11", "up"): 1, ("11", "degraded"): 0, ("11", "down"): 0}
    assert samples(found["mbgw_device_consecutive_failures"], address="2") == \
        {("mbgw_device_consecutive_failures", ()): 3}
    last = found["mbgw_device_last_success_timestamp_seconds"]
    assert sorted(s.labels["address"] for s in last.samples) == ["1", "11"]   # 2 never did


def test_latency_histogram_is_cumulative():
    o = live_objects()
    found = families(render(o.counters, o.devices, o.scheduler, o.server, o.worker, 0.0))
    hist = found["mbgw_transaction_latency_seconds"]
    assert hist.type == "histogram"
    one = samples(hist, address="1")
    buckets = {float(dict(labels)["le"]): v for (name, labels), v in one.items()
               if name.endswith("_bucket")}
    # 1 ms, 3 ms, 3 ms, 700 ms; the per-bucket counts were 1, 2 and (le 1 s) 1
    assert buckets == {0.002: 1, 0.005: 3, 0.01: 3, 0.025: 3, 0.05: 3, 0.1: 3, 0.25: 3,
                       0.5: 3, 1.0: 4, 2.5: 4, 5.0: 4, math.inf: 4}
    assert one[("mbgw_transaction_latency_seconds_count", ())] == 4
    assert one[("mbgw_transaction_latency_seconds_sum", ())] == pytest.approx(0.707)
    eleven = samples(hist, address="11")
    assert eleven[("mbgw_transaction_latency_seconds_bucket", (("le", "5.0"),))] == 0
    assert eleven[("mbgw_transaction_latency_seconds_bucket", (("le", "+Inf"),))] == 1
    two = samples(hist, address="2")
    assert two[("mbgw_transaction_latency_seconds_count", ())] == 0


def test_an_empty_gateway_renders_a_valid_text():
    found = families(render(Counters(), DeviceHealth(), SimpleNamespace(depth=0),
                            SimpleNamespace(clients=[]), SimpleNamespace(up=False), 0.0))
    assert found["mbgw_line_up"].samples[0].value == 0
    assert found["mbgw_device_health"].samples == []


def test_master_mode_renders_its_own_counters_gauges_and_per_address_counts():
    counters = MasterCounters()
    for i, name in enumerate(MASTER_NAMES):
        setattr(counters, name, i + 1)
    devices = DeviceHealth(MASTER_COUNTS)
    three = devices.get(3)
    three.transactions, three.unreachable = 2, 2
    three.failed()
    three.gateway_exception(0x0A)
    slave = SimpleNamespace(up=False, connections=lambda: [{}, {}, {}])
    found = families(render_master(counters, devices, slave, 0.0))
    assert [s.labels["mode"] for s in found["mbgw_info"].samples] == ["master"]
    for i, name in enumerate(MASTER_NAMES):
        assert [s.value for s in found[f"mbgw_{name}"].samples] == [i + 1], name
    assert found["mbgw_unreachable"].documentation.startswith("Requests whose server")
    assert found["mbgw_requests"].documentation.startswith("Requests from the serial master")
    assert found["mbgw_upstream_connections"].samples[0].value == 3
    assert found["mbgw_line_up"].samples[0].value == 0
    assert "mbgw_queue_depth" not in found and "mbgw_line_busy_seconds" not in found
    per_address = {name[len("mbgw_device_"):] for name, f in found.items()
                   if f.type == "counter" and f.samples and "address" in f.samples[0].labels}
    assert per_address == set(MASTER_COUNTS) | {"exception_replies"}
    assert samples(found["mbgw_device_unreachable"], address="3") == \
        {("mbgw_device_unreachable_total", ()): 2}
    assert [(s.labels["code"], s.labels["source"], s.value)
            for s in found["mbgw_device_exception_replies"].samples] == [("0x0a", "gateway", 1)]


def test_a_scrape_reads_the_live_objects():
    o = live_objects()
    collector = slave_collector(o.counters, o.devices, o.scheduler, o.server, o.worker, 0.0)
    before = families(exposition(collector))["mbgw_timeouts"].samples[0].value
    o.counters.timeouts += 7
    o.devices.get(40).transactions = 2
    text = exposition(collector)
    found = families(text)
    assert found["mbgw_timeouts"].samples[0].value == before + 7
    assert samples(found["mbgw_device_transactions"], address="40") == \
        {("mbgw_device_transactions_total", ()): 2}
    assert "_created" not in text


# --- the HTTP server ---------------------------------------------------------------------------

class Scrapes:
    """A collector that counts the scrapes; raises on the first one with fail_first."""

    def __init__(self, fail_first: bool = False) -> None:
        self.count = 0
        self.fail_first = fail_first

    def collect(self):
        self.count += 1
        if self.fail_first and self.count == 1:
            raise RuntimeError("boom")
        yield CounterMetricFamily("mbgw_scrapes", "Scrapes.", value=self.count)


def scraped(body: bytes) -> float:
    """mbgw_scrapes_total in a response body."""
    return families(body.decode())["mbgw_scrapes"].samples[0].value


def _exchange(port: int, data: bytes, host: str = "127.0.0.1") -> bytes:
    """What the server answers to data, up to its end of the connection."""
    with socket.create_connection((host, port), timeout=5) as sock:
        try:
            sock.sendall(data)
        except ConnectionError:         # the server had enough of it already
            pass
        response = b""
        try:
            while chunk := sock.recv(65536):
                response += chunk
        except ConnectionResetError:    # it closed with our bytes unread
            pass
        return response


def _serve(test, collector=None, address: str = "127.0.0.1:1"):
    """Run test(server, port) against a MetricsServer on a free port of address's host."""
    server = MetricsServer(address, collector or Scrapes())
    server.port = 0
    port = int(server.start()[0].rsplit(":", 1)[1])
    try:
        test(server, port)
    finally:
        server.close()


def _split(response: bytes) -> tuple[str, dict, bytes]:
    head, _, body = response.partition(b"\r\n\r\n")
    status, *headers = head.decode().split("\r\n")
    return status, dict(h.split(": ", 1) for h in headers), body


def test_get_metrics_answers_the_text_format_and_closes():
    def test(server, port):
        status, headers, body = _split(_exchange(
            port, b"GET /metrics HTTP/1.1\r\nHost: x\r\nAccept: */*\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK"
        assert headers["Content-Type"] == "text/plain; version=0.0.4; charset=utf-8"
        assert int(headers["Content-Length"]) == len(body)
        assert scraped(body) == 1
        # a registry of its own: no process or interpreter metrics
        assert list(families(body.decode())) == ["mbgw_scrapes"]
        # a query string and a bare LF line end (netcat) are fine too
        status, _, body = _split(_exchange(port, b"GET /metrics?x=1 HTTP/1.0\n\n"))
        assert status == "HTTP/1.0 200 OK" and scraped(body) == 2
    _serve(test)


@pytest.mark.parametrize("request_line, status", [
    (b"GET / HTTP/1.0", "HTTP/1.0 404"),
    (b"GET /metricsx HTTP/1.0", "HTTP/1.0 404"),
    (b"GET /favicon.ico HTTP/1.0", "HTTP/1.0 404"),
    (b"POST /metrics HTTP/1.0", "HTTP/1.0 405"),
    (b"BLAH", "HTTP/1.0 400"),
])
def test_anything_else_is_refused(request_line, status):
    scrapes = Scrapes()

    def test(server, port):
        got, _, body = _split(_exchange(port, request_line + b"\r\n\r\n"))
        assert got.startswith(status + " ") and b"mbgw_scrapes" not in body
    _serve(test, scrapes)
    assert scrapes.count == 0


def test_head_sends_the_headers_only():
    def test(server, port):
        status, headers, body = _split(_exchange(port, b"HEAD /metrics HTTP/1.0\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK" and body == b""
        _, _, get = _split(_exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))
        assert int(headers["Content-Length"]) == len(get)
    _serve(test)


def test_clients_that_stall_or_vanish_do_not_hold_up_a_scrape():
    def test(server, port):
        # one says half a request and waits; one connects and goes; one sends a huge header
        stalled = socket.create_connection(("127.0.0.1", port))
        stalled.sendall(b"GET /metr")
        gone = socket.create_connection(("127.0.0.1", port))
        gone.sendall(b"GET /metrics HTTP/1.0\r\n")
        gone.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\1\0\0\0\0\0\0\0")   # RST
        gone.close()
        flood = _exchange(port, b"GET /metrics HTTP/1.0\r\nX: " + b"a" * 70000 + b"\r\n\r\n")
        assert b"mbgw_scrapes" not in flood
        status, _, body = _split(_exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK" and scraped(body) == 1
        stalled.close()
    _serve(test)


def test_a_collector_bug_costs_one_scrape_only(caplog):
    def test(server, port):
        status, _, body = _split(_exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))
        assert status == "HTTP/1.0 500 Internal Server Error"
        assert body == b"internal error: see the daemon's log\n"
        status, _, body = _split(_exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK" and scraped(body) == 2
    _serve(test, Scrapes(fail_first=True))
    assert [r.message for r in caplog.records if r.name == "mbgw.metrics"] == \
        ["metrics: internal error"]


def test_prometheus_may_ask_for_openmetrics_and_gzip():
    o = live_objects()
    collector = slave_collector(o.counters, o.devices, o.scheduler, o.server, o.worker, 0.0)

    def test(server, port):
        status, headers, body = _split(_exchange(port, b"GET /metrics HTTP/1.0\r\n"
            b"Accept: application/openmetrics-text;version=1.0.0,text/plain;q=0.5\r\n"
            b"Accept-Encoding: gzip\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK"
        assert headers["Content-Type"].startswith("application/openmetrics-text")
        assert headers["Content-Encoding"] == "gzip"
        assert int(headers["Content-Length"]) == len(body)
        text = gzip.decompress(body).decode()
        found = {f.name: f for f in openmetrics_parser.text_string_to_metric_families(text)}
        assert found["mbgw_timeouts"].samples[0].value == o.counters.timeouts
        assert found["mbgw_transaction_latency_seconds"].type == "histogram"
    _serve(test, collector)


def test_every_address_of_the_host_or_one_ipv6_address():
    def get(port: int, host: str) -> str:
        return _split(_exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n", host))[0]
    server = MetricsServer(":1", Scrapes())
    server.port = free_port()
    try:
        assert sorted(server.start()) == [f"0.0.0.0:{server.port}", f"[::]:{server.port}"]
        assert get(server.port, "127.0.0.1") == get(server.port, "::1") == "HTTP/1.0 200 OK"
    finally:
        server.close()

    def test(server, port):
        assert get(port, "::1") == "HTTP/1.0 200 OK"
        with pytest.raises(ConnectionRefusedError):
            get(port, "127.0.0.1")
    _serve(test, address="[::1]:1")


def test_a_taken_port_is_an_error_and_leaves_nothing_listening():
    # [::] taken: 0.0.0.0, which comes first, is had and must be let go
    with socket.socket(socket.AF_INET6) as taken:
        taken.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
        taken.bind(("::", 0))
        taken.listen()
        port = taken.getsockname()[1]
        server = MetricsServer(f":{port}", Scrapes())
        with pytest.raises(OSError) as err:
            server.start()
        assert err.value.errno == errno.EADDRINUSE
    # neither address is held: both can be had again
    with socket.socket(socket.AF_INET6) as v6, socket.socket() as v4:
        v6.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
        v6.bind(("::", port))
        v4.bind(("0.0.0.0", port))


def test_close_stops_listening_and_its_threads():
    server = MetricsServer("127.0.0.1:1", Scrapes())
    server.port = 0
    port = int(server.start()[0].rsplit(":", 1)[1])
    assert _split(_exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))[0] == "HTTP/1.0 200 OK"
    server.close()
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=5)
    assert not [t for t in threading.enumerate() if t.name == f"metrics {port}"]


def test_each_serial_address_has_its_stout_learnt_p99_and_probe_timeout():
    """Slave mode's timing by address (issue 29); no learnt p99 for a device not yet
    answered, whose probe waits the line's learnt time."""
    o = live_objects()
    timed = DeviceHealth(rule=HealthRule(stout_ms=200))
    for _ in range(5):
        timed.get(3).answered(10.0, None)
    timed.get(4).failed()
    collector = slave_collector(o.counters, o.devices, o.scheduler, o.server, o.worker, 0.0,
                                lines=lambda: [("meters", o.counters, timed)])
    found = families(exposition(collector))
    assert samples(found["mbgw_device_stout_seconds"], line="meters") == {
        ("mbgw_device_stout_seconds", (("address", "3"),)): 0.2,
        ("mbgw_device_stout_seconds", (("address", "4"),)): 0.2}
    assert samples(found["mbgw_device_learnt_p99_seconds"], line="meters") == {
        ("mbgw_device_learnt_p99_seconds", (("address", "3"),)): 0.01}
    assert samples(found["mbgw_device_probe_timeout_seconds"], line="meters") == {
        ("mbgw_device_probe_timeout_seconds", (("address", "3"),)): 0.03,
        ("mbgw_device_probe_timeout_seconds", (("address", "4"),)): 0.03}
