"""The scenarios' figures as plain data: the status JSON's "scenarios" section (`mbgw status`,
`mbgw scenarios`), which mbgw.ops.metrics_scenarios turns into the /metrics families (ops does
not import the scenarios).

scenarios_status(engines) -> [
    {"name": "boiler", "kind": "serial" | "tcp", "target": "slave 45" | "host:502 unit 1",
     "function": 3, "trigger": "3000 ms" | "change",
     "state": "starting" | "running" | "error" | "disabled",
     "message": VPGate's error message while in error, why a write waits, else "",
     "runs": n, "successes": n, "errors": {kind: n}, "retries": n, "overruns": n,
     "last_success": Unix time | null, "error_since": Unix time | null (while in error),
     "last_latency_ms": ms | null,
     "data_age_s": s since the last good read | null, "stale": bool,
     "next_probe_in_s": s until its probe while its device (server) is down | null}, ...]
in the configuration's order, serial ones first."""
import time

from mbgw.scenarios.engine import STATES, Scenarios

__all__ = ["STATES", "scenarios_status", "trace_event"]


def scenarios_status(engines) -> list[dict]:
    """Every scenario of the runners' engines (Scenarios, or None for a runner that is not
    there)."""
    rows: list[dict] = []
    for engine in engines:
        if isinstance(engine, Scenarios):
            rows += engine.status()
    return rows


def trace_event(direction: str, scenario, data: bytes, outcome: str,
                latency_ms: float | None = None) -> dict:
    """A trace event (mbgw.ops.trace) of a scenario's run: its request, its reply or "no
    reply"; marked with its name, on the serial line or (a TCP scenario) none."""
    replied = direction != "no reply"
    tcp = scenario.kind == "tcp"
    return {"time": time.time(), "direction": direction, "scenario": scenario.name,
            "client": None, "tid": None, "unit": scenario.unit if tcp else scenario.slave,
            "server": scenario.server if tcp else None, "function": data[0],
            "length": len(data) if replied else 0, "pdu": data.hex() if replied else "",
            "outcome": outcome, "latency_ms": latency_ms, "line": None if tcp else "serial"}
