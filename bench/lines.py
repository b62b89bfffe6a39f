#!/usr/bin/env python3
"""Many lines in one daemon (issue 24).  Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py --lines [--quick]      (or bench/lines.py [--quick])

Two measures, on bench.py's simulated slave (simline slave: FC03 of 10 registers from unit 1,
answered after the wire time of request and reply at 115200, every gap recorded at the slave):

  * eight lines through one listener: eight slaves on ptys of their own; first one direct
    master (simline master) alone, then eight at once, one on each slave, for each line's
    reference in this run; then one `mbgw slave` with `[serial]` and seven `[[line]]`s on the same
    slaves, routes taking unit k to line k's address 1, and CLIENTS closed-loop Modbus TCP
    clients a line, all on the one listener.  Per line: the rate against its direct master
    and against the line's limit (wire time + t3.5 a transaction), the gaps under t3.5 at
    the slave; for mbgw the CPU it used (every thread, from schedstat) and its busiest
    threads.
  * the serial-to-serial bridge: a master (simline master) on a socat pty pair whose other
    end is line "panel" of mbgw in master mode, routed to line serial (slave mode), where a
    slave answers; against the same master reading a second, identical slave directly.  Both
    at the idle pace (the next request t3.5 + 1 ms after a reply), in alternating rounds
    with a third: the same master reading a third slave through a socat pair alone (what
    the pair that carries line panel costs): p50/p99 of the master's latency (request
    written -> reply's last byte) and what mbgw adds.

See README.md, "Many lines".
"""
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench  # noqa: E402  (bench/bench.py, beside this script)
from tests.harness import PtyPair  # noqa: E402

BAUD = 115200
LINES = 8
CLIENTS = 3                  # closed-loop clients a line
T35_US = bench.t35_us(BAUD)
LIMIT_TX_S = 1e6 / (bench.wire_us(BAUD) + T35_US)   # the line's limit: wire time + t3.5
BRIDGE_PAUSE_US = 1000       # the idle pace: beyond t3.5 after each reply


def line_name(k: int) -> str:
    return "serial" if k == 0 else f"l{k + 1}"


def lines_config(path: Path, sides: list) -> None:
    """[[line]]s 2..8 on sides[1:] and routes: unit k+1 to line k's address 1."""
    rows = []
    for k, side in enumerate(sides[1:], 1):
        rows += ["[[line]]", f'name = "{line_name(k)}"', f'device = "{side.device}"',
                 f"baudrate = {BAUD}", "stout = 1000"]
    for k in range(len(sides)):
        rows += ["[[route]]", f'units = "{k + 1}"', f'line = "{line_name(k)}"']
        if k:
            rows.append("address = 1")
    path.write_text("\n".join(rows) + "\n")


def threads_cpu(pid: int) -> dict:
    """CPU ns of each thread of pid, by its name (the C core names the line threads; the
    main thread is "main", the other Python threads "python TID")."""
    by = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            ns = int((task / "schedstat").read_text().split()[0])
        except (OSError, IndexError, ValueError):
            continue
        if task.name == str(pid):
            name = "main"
        elif name == "python":
            name = f"python {task.name}"
        by[name] = by.get(name, 0) + ns
    return by


def direct_all(exe: str, sides: list, seconds: float) -> list:
    """The eight direct masters at once, each on its own slave."""
    for side in sides:
        side.slave.reset()
    procs = [subprocess.Popen([exe, "master", side.device, str(T35_US), str(seconds)],
                              stdout=subprocess.PIPE, text=True) for side in sides]
    runs = []
    for side, proc in zip(sides, procs, strict=True):
        out = proc.communicate()[0].splitlines()
        result, lat = out[0].split(), out[1].split()
        run = bench.Run("direct master")
        run.count, run.seconds = int(result[1]), int(result[2]) / 1e9
        run.errors = int(result[3]) + int(result[4])
        run.latencies = sorted(int(v) for v in lat[1:])
        side.slave.collect(run)
        runs.append(run)
    return runs


def clients_all(port: int, sides: list, warmup: float, seconds: float, pid: int) -> tuple:
    """CLIENTS closed-loop clients a line (unit k+1 for line k), one selector for all.
    Returns the runs, and the CPU each thread of pid used in the measured window (ns)."""
    tallies = [bench.Tally() for _ in sides]
    clients = [(bench.Client(port, k + 1), tallies[k])
               for k in range(len(sides)) for _ in range(CLIENTS)]
    cpu_before: dict = {}
    cpu: dict = {}

    def opens(now: int, due: int) -> bool:
        for side in sides:
            side.slave.reset()
        cpu_before.update(threads_cpu(pid))
        return True

    def closes() -> None:
        cpu.update(_window_cpu(pid, cpu_before))
    window_s = bench.closed_loop(clients, warmup, seconds, opens, closes)
    runs = []
    for side, tally in zip(sides, tallies, strict=True):
        run = bench.Run(f"mbgw, {CLIENTS} clients")
        run.errors, run.count, run.seconds = tally.errors, len(tally.latencies), window_s
        run.span_ns = tally.last - tally.first
        run.latencies = sorted(tally.latencies)
        side.slave.collect(run)
        runs.append(run)
    return runs, cpu


def _window_cpu(pid: int, before: dict) -> dict:
    return {name: ns - before.get(name, 0) for name, ns in threads_cpu(pid).items()}


def eight_lines(exe: str, tmp: Path, warmup: float, seconds: float) -> None:
    sides = []
    gateway = None
    try:
        for _ in range(LINES):
            sides.append(bench.Side(exe, tmp, False, BAUD))
        alone = direct_all(exe, sides[:1], seconds)[0]
        direct = direct_all(exe, sides, seconds)
        config = tmp / "lines.toml"
        lines_config(config, sides)
        # a directory of its own: the gateway's notify socket is named by its port
        gateway = bench.Gateway(Path(tempfile.mkdtemp(dir=tmp)), sides[0].device, "--config",
                                str(config), "--baudrate", str(BAUD), "--stout", "1000",
                                "--max-connections", "64", "--log-level", "warning")
        runs, cpu = clients_all(gateway.port, sides, warmup, seconds, gateway.proc.pid)
        report_lines(sides, direct, runs, seconds)
        print(f"  one direct master alone (line serial, before the eight): {alone.rate:.1f} "
              f"tx/s, {100 * alone.rate / LIMIT_TX_S:.1f} % of the limit, cycle p50 "
              f"{alone.median_cycle_us:.0f} us (the limit's {1e6 / LIMIT_TX_S:.0f} us)")
        wall = seconds * 1e9
        total = sum(r.count for r in runs)
        used = sum(cpu.values())
        print(f"  mbgw's CPU in the window: {100 * used / wall:.0f} % of one CPU, "
              f"{used / 1e3 / max(1, total):.0f} us a transaction; by thread: "
              + ", ".join(f"{n} {100 * ns / wall:.1f} %"
                          for ns, n in sorted(((ns, n) for n, ns in cpu.items()),
                                              reverse=True)[:5]))
    finally:
        if gateway is not None:
            bench._stop_and_show(gateway)
        for side in sides:
            side.stop()


def report_lines(sides: list, direct: list, runs: list, seconds: float) -> None:
    print(f"\nEight lines at {BAUD} through one listener: {CLIENTS} closed-loop clients a "
          f"line; {seconds:g} s; slaves "
          f"{'SCHED_FIFO' if sides[0].slave.policy == 'fifo' else 'SCHED_OTHER'}; line limit "
          f"(wire {bench.wire_us(BAUD):.0f} us + t3.5 {T35_US} us) {LIMIT_TX_S:.1f} tx/s")
    print(f"  {'line':8} {'direct':>7} {'of':>6} {'mbgw':>7} {'of':>7} {'of':>6} {'cycle':>7} "
          f"{'lat':>6} {'lat':>6} {'gap':>5} {'gaps':>9} {'err':>4}")
    print(f"  {'':8} {'tx/s':>7} {'limit':>6} {'tx/s':>7} {'direct':>7} {'limit':>6} "
          f"{'p50 of':>7} {'p50':>6} {'p99':>6} {'min':>5} {'< t3.5':>9} {'':>4}")
    print(f"  {'':8} {'':>7} {'%':>6} {'':>7} {'%':>7} {'%':>6} {'dir. %':>7} "
          f"{'ms':>6} {'ms':>6} {'us':>5} {'':>9} {'':>4}")
    for k, (d, r) in enumerate(zip(direct, runs, strict=True)):
        below = f"{r.gaps_below(T35_US)}/{r.gap_count}"
        print(f"  {line_name(k):8} {d.rate:7.1f} {100 * d.rate / LIMIT_TX_S:6.1f} "
              f"{r.rate:7.1f} {bench._share(r, d):7.1f} {100 * r.rate / LIMIT_TX_S:6.1f} "
              f"{bench._median_share(r, d):7.1f} {r.lat_ms(50):6.2f} {r.lat_ms(99):6.2f} "
              f"{r.gap_us(0):5.0f} {below:>9} {r.errors + r.collisions + r.bad_frames:4d}")
    print("  gap (a reply's end to the next request, at the slave) p50 / p90 / p99, us: "
          "direct " + _gaps(direct) + "; mbgw " + _gaps(runs))
    rates = [bench._share(r, d) for d, r in zip(direct, runs, strict=True)]
    limits = [100 * r.rate / LIMIT_TX_S for r in runs]
    print(f"  all lines: {sum(r.rate for r in runs):.0f} tx/s; of direct "
          f"{min(rates):.1f}..{max(rates):.1f} %, of the limit {min(limits):.1f}.."
          f"{max(limits):.1f} % (aim: >= 97 % of the limit at once)")


def _gaps(runs: list) -> str:
    """The gaps of every line together."""
    gaps = sorted(g for r in runs for g in r.gaps)
    return " / ".join(f"{bench.pct(gaps, q) / 1e3:.0f}" for q in (50, 90, 99))


def bridge(exe: str, tmp: Path, rounds: int, slice_s: float) -> None:
    """A master on line panel (master mode) reads the slave on line serial through mbgw,
    in turns with the same master reading a second slave directly."""
    direct_side = bench.Side(exe, tmp, False, BAUD)
    relayed = bench.Side(exe, tmp, True, BAUD)      # behind a socat pair, as panel is
    bridged = bench.Side(exe, tmp, False, BAUD)
    directory = Path(tempfile.mkdtemp(dir=tmp))
    panel = PtyPair(directory)
    gateway = None
    try:
        config = directory / "bridge.toml"
        config.write_text("\n".join([
            "[[line]]", 'name = "panel"', f'device = "{panel.gateway}"', f"baudrate = {BAUD}",
            'mode = "master"',
            "[[route]]", 'from = "panel"', 'units = "1"', 'line = "serial"']) + "\n")
        gateway = bench.Gateway(directory, bridged.device, "--config", str(config), "--baudrate",
                                str(BAUD), "--stout", "1000", "--log-level", "warning")
        parts = {"direct": [], "socat": [], "bridge": []}
        for _ in range(rounds):
            parts["direct"].append(bench.run_direct(exe, direct_side.device, direct_side.slave,
                                                    T35_US, slice_s, BRIDGE_PAUSE_US))
            parts["socat"].append(bench.run_direct(exe, relayed.device, relayed.slave,
                                                   T35_US, slice_s, BRIDGE_PAUSE_US))
            parts["bridge"].append(bench.run_direct(exe, panel.device, bridged.slave, T35_US,
                                                    slice_s, BRIDGE_PAUSE_US))
        direct = bench.merge("direct read of the slave", parts["direct"])
        socat = bench.merge("direct, through a socat pair", parts["socat"])
        through = bench.merge("through mbgw (panel -> serial)", parts["bridge"])
        report_bridge(direct, socat, through, rounds, slice_s)
    finally:
        if gateway is not None:
            bench._stop_and_show(gateway)
        panel.stop()
        direct_side.stop()
        relayed.stop()
        bridged.stop()


def report_bridge(direct, socat, through, rounds: int, slice_s: float) -> None:
    print(f"\nSerial-to-serial bridge at {BAUD}: simline master, next request t3.5 + "
          f"{BRIDGE_PAUSE_US} us after each reply; {rounds} rounds of {slice_s:g} s each, "
          "in turns")
    print(f"  {'':34} {'tx':>6} {'lat p50':>8} {'lat p99':>8} {'gap min':>8} {'gaps':>9} "
          f"{'err':>4}")
    print(f"  {'':34} {'':>6} {'us':>8} {'us':>8} {'us':>8} {'< t3.5':>9} {'':>4}")
    for r in (direct, socat, through):
        print(f"  {r.name:34} {r.count:6d} {r.lat_ms(50) * 1e3:8.0f} {r.lat_ms(99) * 1e3:8.0f} "
              f"{r.gap_us(0):8.0f} {f'{r.gaps_below(T35_US)}/{r.gap_count}':>9} "
              f"{r.errors + r.collisions + r.bad_frames:4d}")
    added = (through.lat_ms(50) - direct.lat_ms(50)) * 1e3
    relay = (socat.lat_ms(50) - direct.lat_ms(50)) * 1e3
    print(f"  mbgw adds p50 {added:+.0f} us, p99 "
          f"{(through.lat_ms(99) - direct.lat_ms(99)) * 1e3:+.0f} us; of the p50, the socat "
          f"pair that carries line panel (a pty, no wire time) takes {relay:+.0f} us, mbgw "
          f"itself {added - relay:+.0f} us")


def run(quick: bool) -> None:
    seconds, warmup, rounds, slice_s = (1.5, 0.3, 3, 0.5) if quick else (8.0, 0.5, 8, 1.0)
    began = time.monotonic()
    print(f"mbgw lines bench: FC03 read of 10 registers ({bench.REQUEST_LEN}-byte request, "
          f"{bench.REPLY_LEN}-byte reply on the wire) at {BAUD}, t3.5 {T35_US} us")
    print(f"  load average before: {bench._loadavg()} (anything else running skews the "
          "figures)")
    with tempfile.TemporaryDirectory(prefix="mbgw-lines-") as tmp:
        exe = bench.build_simline(Path(tmp))
        eight_lines(exe, Path(tmp), warmup, seconds)
        bridge(exe, Path(tmp), rounds, slice_s)
    print(f"\n({time.monotonic() - began:.0f} s; load average after: {bench._loadavg()})")


def main() -> None:
    bench.quick_main(__doc__, run, "short runs (about 15 s in all)")


if __name__ == "__main__":
    main()
