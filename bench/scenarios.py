#!/usr/bin/env python3
"""The serial scenarios' rows (issue 15): the line as the gateway's own master.  Prints
figures, never pass/fail.

    .venv/bin/python bench/bench.py --scenarios [--quick]     (or bench/scenarios.py [--quick])

The line is bench.py's simulated slave (simline slave: FC03 of 10 registers from unit 1, each
answered after the wire time of request and reply), which records the gap before every request
and the time from one request to the next.  Three runs:

  * saturated: 100 scenarios (FC 3, 10 registers, 100 ms each) at 19200 and 115200: they ask
    for far more than the line carries (100 runs every 100 ms).  The rate of requests on the
    line against the line's limit (wire time + t3.5 a transaction) and against the direct
    master of bench.py on the same slave; the gaps at the slave (none may be below t3.5);
    the scenarios' overruns.
  * a direct-messaging client beside them: one closed-loop Modbus TCP client on the same
    gateway at 115200 while the 100 scenarios saturate the line; its latency, against one
    transaction (it waits for at most the scenario run on the line when it came).
  * period: one 100 ms scenario on an idle line at 115200: the time between two of its
    requests at the slave, minus 100 ms (p50, p99 of its absolute value, and the worst).

See README.md, "Scenarios".
"""
import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench  # noqa: E402  (bench/bench.py, beside this script)

SCENARIOS = 100
CYCLE_MS = 100
STALL_US = 5000


def config(path: Path, baud: int, count: int) -> None:
    lines = ["[serial]", 'mode = "slave"', f"baudrate = {baud}", "stout = 1000",
             "[general]", f'control = "{control_path(path)}"']
    for n in range(count):
        lines += ["[[scenario]]", f'name = "s{n:03d}"', "slave = 1", "function = 3",
                  "address = 0", "quantity = 10", f"table = {10 * n}", f"cycle = {CYCLE_MS}"]
    path.write_text("\n".join(lines) + "\n")


def control_path(config_path: Path) -> Path:
    return config_path.with_suffix(".sock")


def start(tmp: Path, device: str, baud: int, count: int) -> bench.Gateway:
    path = tmp / f"scenarios-{baud}-{count}.toml"
    config(path, baud, count)
    gw = bench.Gateway(tmp, device, "--config", str(path), "--log-level", "warning")
    gw.control = control_path(path)
    return gw


def scenario_status(gw: bench.Gateway) -> list[dict]:
    out = subprocess.run([sys.executable, "-m", "mbgw", "status", "--json", "--control",
                          str(gw.control)], capture_output=True, text=True, cwd=bench.ROOT)
    if out.returncode:
        return []
    return json.loads(out.stdout).get("scenarios", [])


def stalls(run: bench.Run) -> int:
    """Gaps long enough to be the host's (a thread not scheduled), not the gateway's pace."""
    return sum(1 for g in run.gaps if g > STALL_US * 1000)


def window(slave: bench.Slave, name: str, seconds: float) -> bench.Run:
    """What the slave saw over seconds (the gateway running on its own)."""
    run = bench.Run(name)
    slave.reset()
    time.sleep(seconds)
    slave.collect(run)
    run.count = len(run.cycles)
    run.span_ns = sum(run.cycles)
    run.seconds = seconds
    return run


def stop(gw: bench.Gateway) -> None:
    rc = gw.stop()
    log = gw.log_path.read_text().strip()
    if rc or "Traceback" in log:
        print(f"  gateway exit status {rc}; its log:\n    " + log.replace("\n", "\n    "))


def saturated(exe: str, tmp: Path, baud: int, seconds: float, warmup: float,
              with_client: bool) -> None:
    side = bench.Side(exe, tmp, False, baud)
    t35 = bench.t35_us(baud)
    try:
        direct = bench.run_direct(exe, side.device, side.slave, t35, seconds)
        gw = start(tmp, side.device, baud, SCENARIOS)
        try:
            time.sleep(warmup)
            run = window(side.slave, f"{SCENARIOS} scenarios", seconds)
            overruns = sum(s.get("overruns", 0) for s in scenario_status(gw))
            client = bench.run_clients(gw.port, 1, side.slave, warmup, seconds) \
                if with_client else None
        finally:
            stop(gw)
    finally:
        side.stop()
    limit = 1e6 / (bench.wire_us(baud) + t35)
    print(f"\n  {baud} baud, {SCENARIOS} scenarios every {CYCLE_MS} ms (they want "
          f"{SCENARIOS * 1000 / CYCLE_MS:.0f} runs/s; the line's limit is {limit:.1f}/s: "
          f"{bench.wire_us(baud):.0f} us on the wire + t3.5 {t35} us)")
    print(f"    direct master    {direct.rate:8.1f} tx/s  {100 * direct.rate / limit:6.2f} % "
          f"of the limit; gaps p50 {direct.gap_us(50):.0f} / p99 {direct.gap_us(99):.0f} us, "
          f"over {STALL_US} us: {stalls(direct)}")
    print(f"    scenarios        {run.rate:8.1f} tx/s  {100 * run.rate / limit:6.2f} % "
          f"of the limit, {100 * run.rate / direct.rate:6.2f} % of direct; cycle p50 "
          f"{run.median_cycle_us:.0f} us; gaps min {bench.pct(run.gaps, 0) / 1e3:.0f} / p50 "
          f"{run.gap_us(50):.0f} / p99 {run.gap_us(99):.0f} us, below t3.5: "
          f"{run.gaps_below(t35)} of {run.gap_count}, over {STALL_US} us: {stalls(run)}; "
          f"overruns {overruns} (since start)")
    if client is not None:
        print(f"    + 1 TCP client   {client.rate:8.1f} tx/s (its own), latency p50 "
              f"{client.lat_ms(50):.2f} ms, p99 {client.lat_ms(99):.2f} ms (one transaction "
              f"is {(bench.wire_us(baud) + t35) / 1000:.2f} ms); line {client.rate * 2:.1f} "
              f"tx/s if it alternates, gaps below t3.5: {client.gaps_below(t35)}")


def period(exe: str, tmp: Path, baud: int, seconds: float, warmup: float) -> None:
    side = bench.Side(exe, tmp, False, baud)
    try:
        gw = start(tmp, side.device, baud, 1)
        try:
            time.sleep(warmup)
            run = window(side.slave, "one scenario", seconds)
        finally:
            stop(gw)
    finally:
        side.stop()
    errors = sorted(abs(c - CYCLE_MS * 1_000_000) for c in run.cycles)
    print(f"\n  one {CYCLE_MS} ms scenario on an idle line at {baud} baud, {len(errors)} periods: "
          f"period error p50 {bench.pct(errors, 50) / 1e3:.0f} us, p99 "
          f"{bench.pct(errors, 99) / 1e3:.0f} us, worst {bench.pct(errors, 100) / 1e3:.0f} us; "
          f"mean period {run.median_cycle_us / 1e3:.3f} ms (median)")


def run(quick: bool) -> None:
    seconds = {19200: 3.0, 115200: 2.0, "period": 5.0} if quick else \
        {19200: 15.0, 115200: 8.0, "period": 30.0}
    warmup = 0.5
    print("mbgw bench, serial scenarios: FC 3 of 10 registers from unit 1 (simline slave)")
    print(f"  load average before: {bench._loadavg()}")
    began = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-") as tmp_name:
        tmp = Path(tmp_name)
        exe = bench.build_simline(tmp)
        saturated(exe, tmp, 19200, seconds[19200], warmup, with_client=False)
        saturated(exe, tmp, 115200, seconds[115200], warmup, with_client=True)
        period(exe, tmp, 115200, seconds["period"], warmup)
    print(f"\n({time.monotonic() - began:.0f} s; load average after: {bench._loadavg()})")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    run(ap.parse_args().quick)
