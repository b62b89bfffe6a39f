"""The scenarios' figures as plain data: the status JSON's "scenarios" section (`mbgw status`,
`mbgw scenarios`), which mbgw.ops.metrics turns into the /metrics families (ops does not
import the scenarios).

scenarios_status(engines) -> [
    {"name": "boiler", "kind": "serial" | "tcp", "target": "slave 45" | "host:502 unit 1",
     "function": 3, "trigger": "3000 ms" | "change",
     "state": "starting" | "running" | "error" | "disabled",
     "message": VPGate's error message while in error, why a write waits, else "",
     "runs": n, "successes": n, "errors": {kind: n}, "retries": n, "overruns": n,
     "last_success": Unix time | null, "last_latency_ms": ms | null,
     "data_age_s": s since the last good read | null, "stale": bool,
     "next_probe_in_s": s until its probe while its device (server) is down | null}, ...]
in the configuration's order, serial ones first."""
from mbgw.scenarios.engine import STATES, Scenarios

__all__ = ["STATES", "scenarios_status"]


def scenarios_status(engines) -> list[dict]:
    """Every scenario of the runners' engines (Scenarios, or None for a runner that is not
    there)."""
    rows: list[dict] = []
    for engine in engines:
        if isinstance(engine, Scenarios):
            rows += engine.status()
    return rows
