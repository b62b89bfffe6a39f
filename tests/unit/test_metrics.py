"""The Prometheus endpoint (mbgw.ops.metrics): the --metrics address, the exposition text read by
prometheus_client's own parser, and the little HTTP server's behaviour with odd clients."""
import asyncio
import math
from types import SimpleNamespace

import pytest

from mbgw.ops.counters import MASTER_NAMES, NAMES, Counters, MasterCounters
from mbgw.ops.device_stats import MASTER_COUNTS, DeviceTable
from mbgw.errors import ConfigError
from mbgw.ops.metrics import MetricsServer, parse_address, render, render_master


@pytest.mark.parametrize("text, expected", [
    ("127.0.0.1:9502", ("127.0.0.1", 9502)),
    ("0.0.0.0:1", ("0.0.0.0", 1)),
    ("[::1]:9502", ("::1", 9502)),
    ("[::]:65535", ("::", 65535)),
    ("localhost:9502", ("localhost", 9502)),
    (":9502", (None, 9502)),
])
def test_metrics_address(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize("text", ["9502", "127.0.0.1", "127.0.0.1:", "127.0.0.1:0",
                                  "127.0.0.1:65536", "127.0.0.1:http", "::1:9502",
                                  "127.0.0.1:-1"])
def test_bad_metrics_address(text):
    with pytest.raises(ConfigError, match="metrics"):
        parse_address(text)


def live_objects():
    counters = Counters()
    for i, name in enumerate(NAMES):
        setattr(counters, name, i + 1)
    counters.line_busy_ns = 2_500_000_000
    devices = DeviceTable()
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
    parser = pytest.importorskip("prometheus_client.parser")
    return {f.name: f for f in parser.text_string_to_metric_families(text)}


def samples(family, **labels) -> dict:
    """{(sample name, frozenset(labels - given)): value} of the samples matching labels."""
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
    types = [l.split()[2] for l in lines if l.startswith("# TYPE ")]
    assert len(types) == len(set(types))
    assert text.endswith("\n")


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
    found = families(render(Counters(), DeviceTable(), SimpleNamespace(depth=0),
                            SimpleNamespace(clients=[]), SimpleNamespace(up=False), 0.0))
    assert found["mbgw_line_up"].samples[0].value == 0
    assert found["mbgw_device_health"].samples == []


def test_master_mode_renders_its_own_counters_gauges_and_per_address_counts():
    counters = MasterCounters()
    for i, name in enumerate(MASTER_NAMES):
        setattr(counters, name, i + 1)
    devices = DeviceTable(MASTER_COUNTS)
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


# --- the HTTP server ---------------------------------------------------------------------------

async def _exchange(port: int, data: bytes) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(data)
    response = await asyncio.wait_for(reader.read(), 5)
    writer.close()
    return response


def _serve(test):
    """Run test(server, port) against a MetricsServer on a free port of 127.0.0.1."""
    async def main():
        scrapes = []

        def collect():
            scrapes.append(1)
            return f"mbgw_scrapes_total {len(scrapes)}\n"
        server = MetricsServer("127.0.0.1:1", collect)
        server.port = 0
        addresses = await server.start()
        port = int(addresses[0].rsplit(":", 1)[1])
        try:
            await test(server, port)
        finally:
            server.close()
    asyncio.run(main())


def _split(response: bytes) -> tuple[str, dict, bytes]:
    head, _, body = response.partition(b"\r\n\r\n")
    status, *headers = head.decode().split("\r\n")
    return status, dict(h.split(": ", 1) for h in headers), body


def test_get_metrics_answers_the_text_format_and_closes():
    async def test(server, port):
        status, headers, body = _split(await _exchange(
            port, b"GET /metrics HTTP/1.1\r\nHost: x\r\nAccept: */*\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK"
        assert headers["Content-Type"] == "text/plain; version=0.0.4; charset=utf-8"
        assert int(headers["Content-Length"]) == len(body)
        assert body == b"mbgw_scrapes_total 1\n"
        # a query string and a bare LF line end (netcat) are fine too
        status, _, body = _split(await _exchange(port, b"GET /metrics?x=1 HTTP/1.0\n\n"))
        assert status == "HTTP/1.0 200 OK" and body == b"mbgw_scrapes_total 2\n"
    _serve(test)


@pytest.mark.parametrize("request_line, status", [
    (b"GET / HTTP/1.0", "HTTP/1.0 404 Not Found"),
    (b"GET /metricsx HTTP/1.0", "HTTP/1.0 404 Not Found"),
    (b"POST /metrics HTTP/1.0", "HTTP/1.0 405 Method Not Allowed"),
    (b"BLAH", "HTTP/1.0 400 Bad Request"),
])
def test_anything_else_is_refused(request_line, status):
    async def test(server, port):
        got, _, _ = _split(await _exchange(port, request_line + b"\r\n\r\n"))
        assert got == status
    _serve(test)


def test_head_sends_the_headers_only():
    async def test(server, port):
        status, headers, body = _split(await _exchange(port, b"HEAD /metrics HTTP/1.0\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK" and body == b""
        assert int(headers["Content-Length"]) == len(b"mbgw_scrapes_total 1\n")
    _serve(test)


def test_clients_that_stall_or_vanish_do_not_hold_up_a_scrape():
    async def test(server, port):
        # one says half a request and waits; one connects and goes; one sends a huge header
        _, stalled = await asyncio.open_connection("127.0.0.1", port)
        stalled.write(b"GET /metr")
        await stalled.drain()
        _, gone = await asyncio.open_connection("127.0.0.1", port)
        gone.write(b"GET /metrics HTTP/1.0\r\n")
        gone.transport.abort()
        flood = await _exchange(port, b"GET /metrics HTTP/1.0\r\nX: " + b"a" * 20000 +
                                b"\r\n\r\n")
        assert b"mbgw_scrapes_total" not in flood
        status, _, body = _split(await _exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))
        assert status == "HTTP/1.0 200 OK" and body == b"mbgw_scrapes_total 1\n"
        stalled.close()
    _serve(test)


def test_a_render_bug_costs_one_scrape_only():
    async def main():
        calls = []

        def collect():
            calls.append(1)
            if len(calls) == 1:
                raise RuntimeError("boom")
            return "ok 1\n"
        server = MetricsServer("127.0.0.1:1", collect)
        server.port = 0
        port = int((await server.start())[0].rsplit(":", 1)[1])
        try:
            status, _, _ = _split(await _exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))
            assert status == "HTTP/1.0 500 Internal Server Error"
            status, _, body = _split(await _exchange(port, b"GET /metrics HTTP/1.0\r\n\r\n"))
            assert status == "HTTP/1.0 200 OK" and body == b"ok 1\n"
        finally:
            server.close()
    asyncio.run(main())
