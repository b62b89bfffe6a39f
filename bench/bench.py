#!/usr/bin/env python3
"""mbgw throughput, latency and line-gap benchmark.  Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py [--quick] [--socat]

For each line -- 19200 baud, 115200 baud, and a full-speed pty -- a simulated RTU slave
(bench/simline.c, compiled at run time) answers FC03 reads of 10 registers (8-byte request,
25-byte reply).  At 19200 and 115200 it waits, from the request's arrival, the time request
and reply take on the wire (10 bits a character, 8N1) before writing the reply; on the
full-speed pty it answers at once.  Against that slave the script measures:

  * a direct master (simline master): request, reply read by its length, t3.5 of silence
    from the reply's last byte, next request -- the best a master can do on this line;
  * the gateway (python -m mbgw slave) with 1, 5 and 32 closed-loop Modbus TCP clients;
  * the gateway with one client that leaves the line idle between requests (its next request
    comes t3.5 + 1 ms after a reply), for the latency the gateway adds to one transaction.

The slave records every gap between the end of a reply (its write) and the arrival of the next
request, so the gaps are seen from the line's side, not from the gateway's.  See README.md.
"""
import argparse
import math
import os
import platform
import selectors
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from tests.harness import Gateway, PtyPair  # noqa: E402

CHAR_BITS = 10                       # 8N1, what the gateway is started with
REQUEST_LEN, REPLY_LEN = 8, 25       # FC03 of 10 registers on the wire, CRC included
UNIT = 1
REQUEST_PDU = bytes((3, 0, 0, 0, 10))
MBAP = struct.Struct(">HHHB")
TCP_REPLY_LEN = MBAP.size + 2 + 20
CLIENT_COUNTS = (1, 5, 32)
IDLE_EXTRA_S = 0.001                 # the idle-line client's pause beyond t3.5

TARGET_RATE = 97.0                   # % of the direct rate, at line speed
TARGET_ADDED_US = 300.0              # added latency at p50, one client


def t35_us(baud: int) -> int:
    """t3.5 as Serial Line V1.02 2.5.1.1 sets it, with the gateway's 10-bit 8N1 character."""
    if baud > 19200:
        return 1750
    return math.ceil(3.5 * CHAR_BITS * 1_000_000 / baud)


def wire_us(baud: int) -> float:
    return (REQUEST_LEN + REPLY_LEN) * CHAR_BITS * 1e6 / baud


def pct(values: list, q: float):
    """Nearest-rank percentile of sorted values (q in 0..100)."""
    if not values:
        return float("nan")
    rank = max(1, math.ceil(q / 100 * len(values)))
    return values[min(rank, len(values)) - 1]


@dataclass
class Run:
    name: str
    count: int = 0
    seconds: float = 0.0
    latencies: list = field(default_factory=list)     # ns, sorted
    gaps: list = field(default_factory=list)          # ns, sorted
    errors: int = 0
    collisions: int = 0
    bad_frames: int = 0

    @property
    def rate(self) -> float:
        return self.count / self.seconds if self.seconds else 0.0

    @property
    def cycle_us(self) -> float:
        return self.seconds / self.count * 1e6 if self.count else float("nan")

    def lat_ms(self, q: float) -> float:
        return pct(self.latencies, q) / 1e6

    def gap_us(self, q: float) -> float:
        return pct(self.gaps, q) / 1e3

    def gaps_below(self, limit_us: float) -> int:
        return sum(1 for g in self.gaps if g < limit_us * 1000)


# ------------------------------------------------------------------------ the simulated line

def build_simline(directory: Path) -> str:
    exe = directory / "simline"
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        sys.exit("bench: no C compiler (cc) to build bench/simline.c")
    subprocess.run([cc, "-O2", "-Wall", "-o", str(exe), str(HERE / "simline.c")], check=True)
    return str(exe)


class Slave:
    """simline slave: answers on device (None: on a pty of its own) and records the gaps."""

    def __init__(self, exe: str, device: str | None, baud: int) -> None:
        self.proc = subprocess.Popen([exe, "slave", device or "-", str(baud)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline().split()
        if not line or line[0] != "READY":
            raise RuntimeError(f"simline slave did not start: {line}")
        self.device = line[1]

    def _ask(self, command: str) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def reset(self) -> None:
        self._ask("r")
        if self.proc.stdout.readline().strip() != "OK":
            raise RuntimeError("simline slave: no OK to reset")

    def collect(self, run: Run) -> None:
        self._ask("d")
        stats = self.proc.stdout.readline().split()
        gaps = self.proc.stdout.readline().split()
        if stats[:1] != ["STATS"] or gaps[:1] != ["GAPS"]:
            raise RuntimeError(f"simline slave: bad dump {stats[:5]}")
        run.gaps = sorted(int(g) for g in gaps[1:])
        run.collisions, run.bad_frames = int(stats[3]), int(stats[4])

    def stop(self) -> None:
        if self.proc.poll() is None:
            self._ask("q")
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def run_direct(exe: str, device: str, slave: Slave, t35: int, seconds: float) -> Run:
    run = Run("direct master")
    slave.reset()
    out = subprocess.run([exe, "master", device, str(t35), str(seconds)], check=True,
                         capture_output=True, text=True).stdout.splitlines()
    result, lat = out[0].split(), out[1].split()
    run.count, run.seconds = int(result[1]), int(result[2]) / 1e9
    run.errors = int(result[3]) + int(result[4])
    run.latencies = sorted(int(v) for v in lat[1:])
    slave.collect(run)
    return run


# ------------------------------------------------------------------------ Modbus TCP clients

class Client:
    __slots__ = ("sock", "tid", "sent", "buf", "waiting")

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.tid = 0
        self.sent = 0
        self.buf = b""
        self.waiting = False

    def send(self) -> None:
        self.tid = (self.tid + 1) & 0xFFFF
        frame = MBAP.pack(self.tid, 0, len(REQUEST_PDU) + 1, UNIT) + REQUEST_PDU
        self.sent = time.perf_counter_ns()
        self.sock.sendall(frame)
        self.waiting = True

    def reply(self) -> bool | None:
        """Read what came; None: not a whole reply yet; True/False: a good/bad reply."""
        data = self.sock.recv(4096)
        if not data:
            raise ConnectionError("the gateway closed the connection")
        self.buf += data
        if len(self.buf) < TCP_REPLY_LEN:
            return None
        frame, self.buf = self.buf[:TCP_REPLY_LEN], self.buf[TCP_REPLY_LEN:]
        self.waiting = False
        tid, _, _, _ = MBAP.unpack_from(frame)
        return tid == self.tid and frame[7] == 3 and frame[8] == 20


def run_clients(port: int, n: int, slave: Slave, warmup: float, seconds: float) -> Run:
    """n closed-loop clients: each sends its next request as soon as its reply is in."""
    run = Run(f"gateway, {n} client{'s' if n > 1 else ''}")
    clients = [Client(port) for _ in range(n)]
    sel = selectors.DefaultSelector()
    for c in clients:
        c.sock.setblocking(False)
        sel.register(c.sock, selectors.EVENT_READ, c)
    for c in clients:
        c.send()
    start = time.perf_counter_ns() + int(warmup * 1e9)
    end = None
    latencies = []
    drain_until = None
    while True:
        now = time.perf_counter_ns()
        if end is None and now >= start:
            slave.reset()
            start = time.perf_counter_ns()
            end = start + int(seconds * 1e9)
        if end is not None and now >= end and drain_until is None:
            drain_until = now + 5_000_000_000
        if drain_until is not None and (now >= drain_until or not any(c.waiting for c in clients)):
            break
        for key, _ in sel.select(0.1):
            c = key.data
            ok = c.reply()
            if ok is None:
                continue
            done = time.perf_counter_ns()
            if end is not None and start <= done <= end:
                if ok:
                    latencies.append(done - c.sent)
                else:
                    run.errors += 1
            if drain_until is None:
                c.send()
    run.errors += sum(c.waiting for c in clients)     # no reply even after the drain
    for c in clients:
        sel.unregister(c.sock)
        c.sock.close()
    sel.close()
    run.count, run.seconds = len(latencies), (end - start) / 1e9
    run.latencies = sorted(latencies)
    slave.collect(run)
    return run


def run_idle_client(port: int, slave: Slave, t35: int, warmup: float, seconds: float) -> Run:
    """One client that leaves the line idle: its next request comes t3.5 + 1 ms after a
    reply, so no request waits for the line's silence -- the latency is the gateway's."""
    run = Run("gateway, 1 client, idle line")
    c = Client(port)
    pause = t35 / 1e6 + IDLE_EXTRA_S
    latencies = []
    start = time.perf_counter_ns() + int(warmup * 1e9)
    end = None
    while True:
        now = time.perf_counter_ns()
        if end is None and now >= start:
            slave.reset()
            start = time.perf_counter_ns()
            end = start + int(seconds * 1e9)
        if end is not None and now >= end:
            break
        c.send()
        c.sock.settimeout(5)
        ok = None
        while ok is None:
            ok = c.reply()
        done = time.perf_counter_ns()
        if end is not None:
            if ok:
                latencies.append(done - c.sent)
            else:
                run.errors += 1
        time.sleep(pause)
    c.sock.close()
    run.count, run.seconds = len(latencies), (end - start) / 1e9
    run.latencies = sorted(latencies)
    slave.collect(run)
    return run


# ------------------------------------------------------------------------ one line setting

@dataclass
class Line:
    title: str
    baud: int            # the gateway's --baudrate (sets its t3.5)
    paced: bool          # the slave takes the wire time to answer
    seconds: float
    runs: list = field(default_factory=list)
    idle: Run | None = None

    @property
    def t35(self) -> int:
        return t35_us(self.baud)

    @property
    def direct(self) -> Run:
        return self.runs[0]


def measure(line: Line, exe: str, tmp: Path, use_socat: bool, warmup: float) -> None:
    pair = PtyPair(tmp) if use_socat else None
    slave = Slave(exe, pair.device if pair else None, line.baud if line.paced else 0)
    master_device = pair.gateway if pair else slave.device
    gateway = None
    try:
        line.runs.append(run_direct(exe, master_device, slave, line.t35, line.seconds))
        gateway = Gateway(tmp, master_device, "--baudrate", str(line.baud), "--stout", "1000",
                          "--max-connections", str(max(CLIENT_COUNTS) + 8),
                          "--log-level", "warning")
        for n in CLIENT_COUNTS:
            line.runs.append(run_clients(gateway.port, n, slave, warmup, line.seconds))
        line.idle = run_idle_client(gateway.port, slave, line.t35, warmup, line.seconds)
    finally:
        if gateway is not None:
            gateway.stop()
            log = gateway.log_path.read_text().strip()
            if log:
                print(f"  gateway log:\n    " + log.replace("\n", "\n    "))
        slave.stop()
        if pair:
            pair.stop()


# ------------------------------------------------------------------------ report

def report_line(line: Line) -> None:
    d = line.direct
    if line.paced:
        head = (f"{line.title}: slave answers after the wire time, "
                f"{wire_us(line.baud):.0f} us a transaction ({REQUEST_LEN}+{REPLY_LEN} chars x "
                f"{CHAR_BITS} bits)")
    else:
        head = f"{line.title}: slave answers at once (gateway at --baudrate {line.baud})"
    print(f"\n{head}; t3.5 {line.t35} us; {line.seconds:g} s a run")
    print(f"  {'':30} {'tx/s':>7} {'of direct':>9} {'lat p50':>8} {'lat p99':>8} "
          f"{'ideal':>8} {'gap min':>8} {'gap p50':>8} {'gaps<t3.5':>10}")
    print(f"  {'':30} {'':>7} {'':>9} {'ms':>8} {'ms':>8} {'lat ms':>8} {'us':>8} {'us':>8} "
          f"{'':>10}")
    for i, r in enumerate(line.runs + [line.idle]):
        clients = CLIENT_COUNTS[i - 1] if 0 < i <= len(CLIENT_COUNTS) else 1
        # A closed loop of k clients on one line: each waits k cycles of the direct master.
        ideal = f"{clients * d.cycle_us / 1000:8.3f}" if r is not line.idle else f"{d.lat_ms(50):8.3f}"
        share = f"{100 * r.rate / d.rate:8.1f}%" if r is not line.idle else f"{'-':>9}"
        rate = f"{r.rate:7.1f}" if r is not line.idle else f"{'-':>7}"
        below = f"{r.gaps_below(line.t35)}/{len(r.gaps)}"
        print(f"  {r.name:30} {rate} {share} {r.lat_ms(50):8.3f} {r.lat_ms(99):8.3f} {ideal} "
              f"{r.gap_us(0):8.0f} {r.gap_us(50):8.0f} {below:>10}")
    added = (line.idle.lat_ms(50) - d.lat_ms(50)) * 1000
    print(f"  added latency at p50, 1 client on an idle line: {added:+.0f} us "
          f"(p99 {(line.idle.lat_ms(99) - d.lat_ms(99)) * 1000:+.0f} us)")
    gw = line.runs[-1]
    print(f"  line cycle, line saturated (32 clients): gateway {gw.cycle_us:.0f} us, direct "
          f"{d.cycle_us:.0f} us: gateway adds {gw.cycle_us - d.cycle_us:+.0f} us a transaction; "
          f"gap p50 {gw.gap_us(50) - d.gap_us(50):+.0f} us over the direct master's")
    for r in line.runs + [line.idle]:
        if r.errors or r.collisions or r.bad_frames:
            print(f"  !! {r.name}: {r.errors} failed transactions, {r.collisions} requests over a "
                  f"reply, {r.bad_frames} bad frames at the slave")


def summary(lines: list) -> None:
    print("\nAgainst the issue's targets (figures only; mbusd for reference: 75 % of direct at "
          "115200, ~1 ms added)")
    print(f"  {'':22} {'rate of direct, 1/5/32 clients':>32} {'smallest gap':>13} "
          f"{'t3.5':>6} {'added p50':>10}")
    for line in lines:
        d = line.direct
        shares = " / ".join(f"{100 * r.rate / d.rate:.1f}" for r in line.runs[1:])
        gap = min(r.gap_us(0) for r in line.runs[1:] + [line.idle])
        added = (line.idle.lat_ms(50) - d.lat_ms(50)) * 1000
        print(f"  {line.title:22} {shares + ' %':>32} {gap:10.0f} us {line.t35:6d} "
              f"{added:+7.0f} us")
    print(f"  {'target':22} {f'>= {TARGET_RATE:g} % at line speed':>32} "
          f"{'>= t3.5':>13} {'':6} {f'<= {TARGET_ADDED_US:.0f} us':>10}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs (under 30 s in all)")
    ap.add_argument("--socat", action="store_true",
                    help="put the line on a socat pty pair (as the tests do) instead of one pty")
    args = ap.parse_args()
    if args.quick:
        secs, warmup = {19200: 1.5, 115200: 1.0, 0: 1.0}, 0.2
    else:
        secs, warmup = {19200: 8.0, 115200: 5.0, 0: 4.0}, 0.3
    lines = [Line("19200 baud", 19200, True, secs[19200]),
             Line("115200 baud", 115200, True, secs[115200]),
             Line("full-speed pty", 115200, False, secs[0])]
    began = time.monotonic()
    print(f"mbgw bench: FC03 read of 10 registers from unit 1 ({REQUEST_LEN}-byte request, "
          f"{REPLY_LEN}-byte reply on the wire)")
    print(f"  host {platform.node()}: {os.cpu_count()} CPUs, Linux {platform.release()}, "
          f"Python {platform.python_version()}; line on "
          f"{'a socat pty pair' if args.socat else 'one pty (no relay)'}")
    print(f"  t3.5 checked against the gateway's own figure for --format 8n1 (10-bit character): "
          f"{t35_us(19200)} us at 19200, 1750 us above; the spec's 11-bit character would give "
          f"{math.ceil(3.5 * 11e6 / 19200)} us at 19200")
    print("  latency: request sent -> whole reply read, by the TCP client (gateway) or the "
          "master (direct); gaps: end of a reply -> arrival of the next request, at the slave")
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-") as tmp:
        tmp = Path(tmp)
        exe = build_simline(tmp)
        for line in lines:
            measure(line, exe, tmp, args.socat, warmup)
            report_line(line)
    summary(lines)
    print(f"\n({time.monotonic() - began:.0f} s)")


if __name__ == "__main__":
    main()
