"""The serial addresses' metric families, labelled by line and address: their counters,
exception replies, health, timing and latency, from the lines' device tables
(mbgw.ops.device_stats)."""
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily

from mbgw.ops.device_stats import DEGRADED, DOWN, LATENCY_BUCKETS_MS, UP
from mbgw.ops.metrics_histogram import cumulative_buckets

_DEVICE_HELP = {
    "transactions": "Requests sent to this serial address (broadcasts included).",
    "replies": "Valid replies from this serial address (exception replies included).",
    "timeouts": "Transactions with this address that ended without a valid reply.",
    "retries": "Requests to this address repeated after no valid reply.",
    "crc_errors": "Frames with a bad CRC or LRC while waiting for this address.",
    "invalid_frames": "Malformed frames while waiting for this address.",
    "wrong_unit": "Frames from another address while waiting for this one.",
    "wrong_function": "Replies from this address with another function or size.",
    "late_replies": "Replies from this address after the slave timeout.",
    "broadcasts": "Broadcasts (address 0).",
    "demoted_rejects": "Requests for this address refused while it was down (not probes).",
    "unreachable": "Requests for this address whose server could not be reached.",
    "abandoned": "Answers for this address not written: the master had moved on.",
}


_MASTER_DEVICE_HELP = {
    "transactions": "Requests from the master to this serial address, sent to its server.",
    "replies": "Replies from this address's server (exception replies included).",
    "timeouts": "Requests to this address its server did not answer within tcpto.",
    "wrong_unit": "Replies from this address's server with another unit id than the one sent.",
    "wrong_function": "Replies from this address's server with another function, size or echo.",
    "invalid_frames": "Replies from this address's server with a bad MBAP header.",
    "demoted_rejects": "Requests for this address answered at once while it was down (not "
                       "probes): not sent to its server.",
}


def device_families(table, counts, master: bool):
    """Every serial address's families; table: (line, device) of every address of every line,
    counts: the names of the counters the mode keeps."""
    yield from _device_counters(table, counts, master)
    yield from _device_health(table)
    if not master:
        yield from _device_timing(table)
    yield _latency(table, master)


def _device_counters(table, counts, master: bool):
    for name in counts:
        help_text = (master and _MASTER_DEVICE_HELP.get(name)) or _DEVICE_HELP[name]
        family = CounterMetricFamily(f"mbgw_device_{name}",
                                     help_text + " By line and serial address.",
                                     labels=["line", "address"])
        for line, d in table:
            if name in d.counts:
                family.add_metric([line, str(d.address)], getattr(d, name))
        yield family
    family = CounterMetricFamily(
        "mbgw_device_exception_replies", "Exception replies by serial address and "
        "exception code; source: the device (in master mode its server) sent it, or the "
        "gateway generated it (0x0B: no reply, 0x0A: line down or server unreachable).",
        labels=["line", "address", "code", "source"])
    for line, d in table:
        for source, by_code in (("device", d.exceptions),
                                ("gateway", d.gateway_exceptions)):
            for code, n in sorted(dict(by_code).items()):
                family.add_metric([line, str(d.address), f"0x{code:02x}", source], n)
    yield family


def _device_health(table):
    health = GaugeMetricFamily(
        "mbgw_device_health", "Health of the serial address: 1 for its current state "
        "(up: its recent requests were answered; degraded: some failed; down: the last "
        "down-after failed in a row, its requests are refused but for probes), 0 for the "
        "others.", labels=["line", "address", "state"])
    since = GaugeMetricFamily(
        "mbgw_device_health_since_seconds",
        "When the serial address entered its current health state (Unix time).",
        labels=["line", "address"])
    failures = GaugeMetricFamily(
        "mbgw_device_consecutive_failures",
        "Transactions in a row without a valid reply, by serial address.",
        labels=["line", "address"])
    success = GaugeMetricFamily(
        "mbgw_device_last_success_timestamp_seconds",
        "When the serial address last answered (Unix time); absent if it never did.",
        labels=["line", "address"])
    for line, d in table:
        address = str(d.address)
        for state in (UP, DEGRADED, DOWN):
            health.add_metric([line, address, state], 1 if d.health == state else 0)
        since.add_metric([line, address], round(d.health_since, 3))
        failures.add_metric([line, address], d.consecutive_failures)
        if d.last_success is not None:
            success.add_metric([line, address], round(d.last_success, 3))
    yield from (health, since, failures, success)


def _device_timing(table):
    """Slave mode: each address's stout (its [[device]] one or the line's), the p99 of
    its last answers' latency and how long its probe waits (demotion)."""
    stout = GaugeMetricFamily(
        "mbgw_device_stout_seconds", "The serial address's response timeout: its "
        "[[device]] stout, else the line's.", labels=["line", "address"])
    p99 = GaugeMetricFamily(
        "mbgw_device_learnt_p99_seconds", "The p99 of the latency of the serial "
        "address's last 100 answers; absent before its first.", labels=["line", "address"])
    probe = GaugeMetricFamily(
        "mbgw_device_probe_timeout_seconds", "How long a probe of the serial address waits "
        "for its reply while it is down: 3 x its learnt p99, at least 20 ms, at most its "
        "stout.", labels=["line", "address"])
    for line, d in table:
        if not d.stout_ms:
            continue
        address = str(d.address)
        stout.add_metric([line, address], d.stout_ms / 1000)
        probe.add_metric([line, address], d.probe_timeout_ms() / 1000)
        learnt = d.learnt_p99_ms()
        if learnt is not None:
            p99.add_metric([line, address], learnt / 1000)
    yield from (stout, p99, probe)


def _latency(table, master: bool):
    family = HistogramMetricFamily(
        "mbgw_transaction_latency_seconds",
        "Time from receiving the master's request to its server's reply, by serial "
        "address." if master else
        "Time from sending a request on the line to the end of its valid reply "
        "(the last try's, after retries), by serial address.", labels=["line", "address"])
    for line, d in table:
        family.add_metric([line, str(d.address)],
                          cumulative_buckets(LATENCY_BUCKETS_MS, list(d.latency_buckets)),
                          d.latency_sum_ms / 1000)
    return family
