"""What an operator runs against a running gateway, for the diagnostics tests of both modes:
`python -m mbgw ...` over the control socket, the daemon's status polled until a condition
holds, its log, and the Prometheus text parsed by prometheus_client's parser."""
import contextlib
import json
import pathlib
import re
import subprocess
import sys
import urllib.request

from prometheus_client import parser

from mbgw.ops import control
from tests.harness import CHECKOUT, _read_lines_until, reachable_by_others
from tests.wait import until

CONDITION_TIMEOUT_S = 5.0       # for what the daemon does on its own after the last event


def mbgw(*args: str, user: str | None = None, groups: str | None = None,
         timeout: float = 15) -> subprocess.CompletedProcess:
    """`python -m mbgw ARGS`; as user (with these supplementary groups) when asked."""
    command = [sys.executable, "-m", "mbgw", *args]
    if user is None:
        return subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    command = ["setpriv", f"--reuid={user}", "--regid=nogroup",
               f"--groups={groups}" if groups else "--clear-groups", *command]
    with reachable_by_others():
        return subprocess.run(command, capture_output=True, text=True, timeout=timeout,
                              cwd=CHECKOUT)


def line_threads(gw) -> list[str]:
    """The kernel's names of the daemon's threads that name themselves mbgw-... (what `ps -L`
    shows), sorted."""
    tasks = pathlib.Path(f"/proc/{gw.proc.pid}/task")
    names = (t.joinpath("comm").read_text().strip() for t in tasks.iterdir())
    return sorted(name for name in names if name.startswith("mbgw-"))


def status(gw) -> dict:
    """`mbgw status --json`, as an operator runs it."""
    result = mbgw("status", "--json", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def wait_for(gw, condition, what: str) -> dict:
    """The daemon's status once condition(status) holds (it is polled over the control socket,
    in process: the daemon does this on its own, after the last event a test can see)."""
    seen: list[dict] = [{}]

    def holding() -> dict | None:
        seen[0] = control.call(gw.control, {"command": "status"})
        return seen[0] if condition(seen[0]) else None

    return until(holding, lambda: f"{what}: {seen[0]}", CONDITION_TIMEOUT_S)


def wait_for_log(gw, text: str, count: int = 1, timeout: float = CONDITION_TIMEOUT_S) -> str:
    """The gateway's log once text stands in it count times."""
    return until(lambda: (log := gw.log()).count(text) >= count and log,
                 lambda: f"{text!r} in the log:\n{gw.log()}", timeout)


def devices(s: dict) -> dict[int, dict]:
    """A status's devices by address."""
    return {d["address"]: d for d in s["devices"]}


def health_log(gw, address: int) -> list[str]:
    """The health states the daemon logged for this address, in order."""
    pattern = re.compile(rf"mbgw\.devices: device {address} is (up|degraded|down)\b")
    return [m.group(1) for m in map(pattern.search, gw.log().splitlines()) if m]


def metric_families(parser, text: str) -> dict:
    """The metric families of a /metrics text by name (parser: prometheus_client.parser);
    every one must be documented and of a known type."""
    families = {f.name: f for f in parser.text_string_to_metric_families(text)}
    for f in families.values():
        assert f.documentation and f.type in ("counter", "gauge", "histogram"), f.name
    return families


def scraped(port: int) -> dict:
    """The metric families http://127.0.0.1:PORT/metrics serves now, checked as
    metric_families checks them."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as page:
        return metric_families(parser, page.read().decode())


def metric_value(families: dict, metric: str, sample: str | None = None, **labels) -> float:
    """The value of the one sample (metric's own unless named) with these labels."""
    found = [x.value for x in families[metric].samples
             if x.name == (sample or metric) and
             all(x.labels.get(k) == str(v) for k, v in labels.items())]
    assert len(found) == 1, (metric, labels, found)
    return found[0]


@contextlib.contextmanager
def tracing(gw, pcap, count: int, *options: str):
    """`mbgw trace --pcap PCAP --count COUNT OPTIONS` on gw's control socket: yields (the
    process, its first line), the column header, which comes once the daemon has taken the
    subscription.  Killed on the way out if still running."""
    trace = subprocess.Popen([sys.executable, "-m", "mbgw", "trace", "--pcap", str(pcap),
                              "--count", str(count), *options, "--control", gw.control],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        yield trace, _read_lines_until(trace, trace.stdout, lambda ls: len(ls) >= 1, 10)
    finally:
        if trace.poll() is None:
            trace.kill()
            trace.wait()


def tshark_warnings(pcap, port: int) -> subprocess.CompletedProcess:
    """tshark on the pcap, Modbus TCP on port, showing only malformed packets and expert
    warnings (or worse)."""
    return subprocess.run(["tshark", "-r", str(pcap), "-o", f"mbtcp.tcp.port:{port}",
                           "-Y", "_ws.malformed || _ws.expert.severity >= warning"],
                          capture_output=True, text=True, timeout=60)
