#!/usr/bin/env python3
"""mbgw throughput, latency and line-gap benchmark.  Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py [--quick] [--socat] [--fairness | --table | --tls |
                                     --scenarios | --lines | --mqtt]

For each line -- 19200 baud, 115200 baud, and a full-speed pty -- a simulated RTU slave
(bench/simline.c, compiled at run time) answers FC03 reads of 10 registers (8-byte request,
25-byte reply).  At 19200 and 115200 it waits, from the request's arrival, the time request
and reply take on the wire (10 bits a character, 8N1) before writing the reply; on the
full-speed pty it answers at once.  Against that slave the script measures:

  * a direct master (simline master): request, reply read by its length, t3.5 of silence
    from the reply's last byte, next request -- the best a master can do on this line;
  * the gateway (python -m mbgw slave) with 1, 5 and 32 closed-loop Modbus TCP clients;
  * the gateway with one client that leaves the line idle between requests (its next request
    comes t3.5 + 1 ms after a reply), for the latency the gateway adds to one transaction,
    in rounds that alternate with the direct master and with the least gateway there can be
    (simline relay: C, one thread, no checks) at the same pace, each on a slave of its own.

The slave records every gap between the end of a reply (its write) and the arrival of the next
request, so the gaps are seen from the line's side, not from the gateway's.

--fairness measures instead a dead unit beside closed-loop clients (issue 13: their share of
the line, their slowest request) and the per-client spread of transactions.  --table measures
instead the exchange table as a Modbus TCP server (bench/table.py); --scenarios the serial
scenarios (bench/scenarios.py).  See README.md.
"""
import argparse
import importlib
import math
import os
import platform
import re
import selectors
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from mbgw.ops import control  # noqa: E402
from tests.harness import Peer, PtyPair, free_port  # noqa: E402

CHAR_BITS = 10                       # 8N1, what the gateway is started with
REQUEST_LEN, REPLY_LEN = 8, 25       # FC03 of 10 registers on the wire, CRC included
UNIT = 1
REQUEST_PDU = bytes((3, 0, 0, 0, 10))
MBAP = struct.Struct(">HHHB")
TCP_REPLY_LEN = MBAP.size + 2 + 20
CLIENT_COUNTS = (1, 5, 32)
IDLE_EXTRA_S = 0.001                 # the idle-line client's pause beyond t3.5

# How the gateway is started (an experiment may put a wrapper in front).
GATEWAY_COMMAND = [sys.executable, "-m", "mbgw", "slave"]
READY_TIMEOUT_S = 15.0
READY_POLL_S, READY_LIMIT_S = 0.2, 30.0   # run_clients' ready()
# A reply's write() to the pty takes a few microseconds, often 100-200 us on an idle VM (the
# wake-up of the pty's kworker on a halted vCPU); the gap is measured from the write's end,
# which can only make it read short.  When the slave was held up longer (a vCPU stolen by the
# host: seen up to 1.5 ms even under SCHED_FIFO), the reply's end is only known to lie within
# the write, and its gap is left out of the gap figures.
HELD_WRITE_NS = 250_000

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
    span_ns: int = 0      # first to last completion (closed-loop runs): count - 1 cycles
    gaps: list = field(default_factory=list)          # ns, sorted
    errors: int = 0
    collisions: int = 0
    bad_frames: int = 0
    held: list = field(default_factory=list)   # (gap, write) ns where the write was slow
    timed: list = field(default_factory=list)  # (gap, write) ns of every gap
    cycles: list = field(default_factory=list)    # ns from request to request, at the slave
    per_client: list = field(default_factory=list)  # transactions of each client, sorted
    ready: bool = True    # the window began once run_clients' ready() held (not on a limit)

    @property
    def rate(self) -> float:
        """Transactions a second.  From the spacing of the completions when known: a count
        over a window is off by up to one transaction (1.3 % of 77 in 1.5 s at 19200)."""
        if self.span_ns and self.count > 1:
            return (self.count - 1) / (self.span_ns / 1e9)
        return self.count / self.seconds if self.seconds else 0.0

    @property
    def cycle_us(self) -> float:
        return 1e6 / self.rate if self.rate else float("nan")

    @property
    def median_cycle_us(self) -> float:
        """The line's typical cycle as the slave sees it: unlike the rate, not moved by the
        host's stalls (this VM's vCPUs are sometimes gone for milliseconds)."""
        return pct(self.cycles, 50) / 1e3

    def lat_ms(self, q: float) -> float:
        return pct(self.latencies, q) / 1e6

    def gap_us(self, q: float) -> float:
        return pct(self.gaps, q) / 1e3

    def gaps_below(self, limit_us: float) -> int:
        """Gaps certainly shorter than limit_us: short even if the reply ended when the
        slave's write began (the gateway cannot have seen it sooner)."""
        limit = limit_us * 1000
        return sum(1 for g, w in self.timed if g + w < limit)

    def gaps_unsure(self, limit_us: float) -> list:
        """(gap, write) of the gaps that are below limit_us measured from the end of the
        slave's write and above it measured from its start: which, the bench cannot tell."""
        limit = limit_us * 1000
        return [(g, w) for g, w in self.timed if g < limit <= g + w]

    @property
    def gap_count(self) -> int:
        return len(self.gaps) + len(self.held)


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

    def __init__(self, exe: str, device: str | None, baud: int,
                 dying: tuple[int, int] | None = None) -> None:
        """dying: (unit, n): that unit is answered its first n reads, then never."""
        dies = [str(v) for v in dying] if dying else []
        self.proc = subprocess.Popen([exe, "slave", device or "-", str(baud), *dies],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline().split()
        if not line or line[0] != "READY":
            raise RuntimeError(f"simline slave did not start: {line}")
        self.device = line[1]
        self.policy = line[2]           # "fifo": real-time, ahead of the gateway; else "other"

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
        records = [tuple(int(v) for v in g.split(",")) for g in gaps[1:]]
        run.gaps = sorted(g for g, w, _ in records if w <= HELD_WRITE_NS)
        run.held = sorted((g, w) for g, w, _ in records if w > HELD_WRITE_NS)
        run.timed = sorted((g, w) for g, w, _ in records)
        run.cycles = sorted(c for _, _, c in records)
        run.collisions, run.bad_frames = int(stats[3]), int(stats[4])

    def stop(self) -> None:
        if self.proc.poll() is None:
            self._ask("q")
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def run_direct(exe: str, device: str, slave: Slave, t35: int, seconds: float,
               pause_us: int = 0) -> Run:
    run = Run("direct master")
    slave.reset()
    out = subprocess.run([exe, "master", device, str(t35), str(seconds), str(pause_us)],
                         check=True, capture_output=True, text=True).stdout.splitlines()
    result, lat = out[0].split(), out[1].split()
    run.count, run.seconds = int(result[1]), int(result[2]) / 1e9
    run.errors = int(result[3]) + int(result[4])
    run.latencies = sorted(int(v) for v in lat[1:])
    slave.collect(run)
    return run


# ------------------------------------------------------------------------ the gateway

class Gateway:
    """python -m mbgw slave on 127.0.0.1, ready when it sends READY=1.  The notify socket
    stays bound until the gateway has stopped, so its STOPPING=1 lands somewhere, as under
    systemd (tests/harness.py closes it after READY)."""

    def __init__(self, tmp: Path, device: str, *options: str) -> None:
        self.port = free_port()
        self.log_path = tmp / f"mbgw-{self.port}.log"
        self.control = str(tmp / f"control-{self.port}")
        notify_path = str(tmp / f"notify-{self.port}")
        self._notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._notify.bind(notify_path)
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen(
            [*GATEWAY_COMMAND, "--device", device, "--bind", "127.0.0.1",
             "--mdbport", str(self.port), "--control", self.control, *options],
            env=dict(os.environ, NOTIFY_SOCKET=notify_path), stdout=self._log, stderr=self._log)
        self._notify.settimeout(READY_TIMEOUT_S)
        try:
            while b"READY=1" not in self._notify.recv(4096):
                pass
        except socket.timeout:
            self.stop()
            raise RuntimeError(f"gateway not ready: {self.log_path.read_text()}") from None

    def device(self, unit: int) -> dict | None:
        """What `mbgw status --json` says of a serial address (None: nothing yet)."""
        found = control.call(self.control, {"command": "status"}).get("devices", [])
        return next((d for d in found if d["address"] == unit), None)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        self._notify.close()
        return self.proc.returncode


# ------------------------------------------------------------------------ Modbus TCP clients

class Client:
    __slots__ = ("sock", "tid", "sent", "buf", "waiting", "unit", "count")

    def __init__(self, port: int, unit: int = UNIT) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.unit = unit
        self.tid = 0
        self.sent = 0
        self.buf = b""
        self.waiting = False
        self.count = 0          # good replies in the measured window

    def send(self) -> None:
        self.tid = (self.tid + 1) & 0xFFFF
        frame = MBAP.pack(self.tid, 0, len(REQUEST_PDU) + 1, self.unit) + REQUEST_PDU
        self.sent = time.perf_counter_ns()
        self.sock.sendall(frame)
        self.waiting = True

    def reply(self) -> bool | None:
        """Read what came; None: not a whole reply yet; True/False: a good/bad reply (an
        exception is a bad one)."""
        data = self.sock.recv(4096)
        if not data:
            raise ConnectionError("the gateway closed the connection")
        self.buf += data
        if len(self.buf) < MBAP.size:
            return None
        size = 6 + MBAP.unpack_from(self.buf)[2]
        if len(self.buf) < size:
            return None
        frame, self.buf = self.buf[:size], self.buf[size:]
        self.waiting = False
        tid, _, _, _ = MBAP.unpack_from(frame)
        return size == TCP_REPLY_LEN and tid == self.tid and frame[7] == 3 and frame[8] == 20


@dataclass
class Tally:
    """What one group of closed-loop clients got in the measured window."""
    latencies: list = field(default_factory=list)     # ns, as they came
    errors: int = 0
    first: int = 0      # the first completion (perf_counter ns)
    last: int = 0

    def take(self, c: "Client", ok: bool, done: int) -> None:
        """c's reply, good or not, completed at done within the window."""
        self.first = self.first or done
        self.last = done
        if ok:
            self.latencies.append(done - c.sent)
            c.count += 1
        else:
            self.errors += 1


def closed_loop(clients: list, warmup: float, seconds: float,
                opens: Callable[[int, int], bool],
                closes: Callable[[], None] | None = None) -> float:
    """Clients, each (Client, the Tally it counts into or None: not measured), in a closed
    loop: each sends its next request as soon as its reply is in, one selector for all.
    The window opens after the warm-up, once opens(now, when it was due) says so (asked
    again every READY_POLL_S), and lasts seconds; closes() is called as it ends.  Then the
    replies still due are waited for up to 5 s; a reply that never came is an error.
    Returns the window's length (s)."""
    sel = selectors.DefaultSelector()
    for c, tally in clients:
        c.sock.setblocking(False)
        sel.register(c.sock, selectors.EVENT_READ, (c, tally))
    for c, _ in clients:
        c.send()
    due = start = time.perf_counter_ns() + int(warmup * 1e9)
    end = None
    drain_until = None
    while True:
        now = time.perf_counter_ns()
        if end is None and now >= start:
            if not opens(now, due):
                start = now + int(READY_POLL_S * 1e9)
            else:
                start = time.perf_counter_ns()
                end = start + int(seconds * 1e9)
        if end is not None and now >= end and drain_until is None:
            if closes is not None:
                closes()
            drain_until = now + 5_000_000_000
        if drain_until is not None and (now >= drain_until
                                        or not any(c.waiting for c, _ in clients)):
            break
        for key, _ in sel.select(0.1):
            c, tally = key.data
            ok = c.reply()
            if ok is None:
                continue
            done = time.perf_counter_ns()
            if tally is not None and end is not None and start <= done <= end:
                tally.take(c, ok, done)
            if drain_until is None:
                c.send()
    _close(sel, clients)
    assert end is not None
    return (end - start) / 1e9


def _close(sel: selectors.BaseSelector, clients: list) -> None:
    for c, tally in clients:
        if tally is not None:
            tally.errors += c.waiting    # no reply even after the drain
        sel.unregister(c.sock)
        c.sock.close()
    sel.close()


def run_clients(port: int, n: int, slave: Slave, warmup: float, seconds: float,
                others: int = 0, other_unit: int = 0,
                ready: Callable[[], bool] | None = None) -> Run:
    """n closed-loop clients: each sends its next request as soon as its reply is in; and
    `others` more on other_unit, also in a closed loop, whose replies are neither counted
    nor timed (nor errors: a dead unit's 0x0B).  ready: the window begins after the warm-up
    once it holds (asked every READY_POLL_S), READY_LIMIT_S later at the latest."""
    run = Run(f"gateway, {n} client{'s' if n > 1 else ''}")
    measured = [Client(port) for _ in range(n)]
    tally = Tally()

    def opens(now: int, due: int) -> bool:
        if _not_ready(run, ready, now, due + int(READY_LIMIT_S * 1e9)):
            return False
        slave.reset()
        return True
    run.seconds = closed_loop([(c, tally) for c in measured]
                              + [(Client(port, other_unit), None) for _ in range(others)],
                              warmup, seconds, opens)
    run.errors += tally.errors
    run.count, run.span_ns = len(tally.latencies), tally.last - tally.first
    run.latencies = sorted(tally.latencies)
    run.per_client = sorted(c.count for c in measured)
    slave.collect(run)
    return run


def _not_ready(run: Run, ready: Callable[[], bool] | None, now: int, ready_by: int) -> bool:
    """Whether the window waits for ready(); past ready_by it waits no more (run.ready
    says so)."""
    if ready is None or ready():
        return False
    run.ready = now < ready_by
    return run.ready


def run_idle_client(port: int, slave: Slave | None, t35: int, warmup: float,
                    seconds: float) -> Run:
    """One client that leaves the line idle: its next request comes t3.5 + 1 ms after a
    reply, so no request waits for the line's silence -- the latency is the gateway's."""
    run = Run("gateway, 1 client, idle line")
    c = Client(port)
    c.sock.settimeout(5)
    pause = t35 / 1e6 + IDLE_EXTRA_S
    latencies = []
    start = time.perf_counter_ns() + int(warmup * 1e9)
    end = None
    while True:
        now = time.perf_counter_ns()
        if end is None and now >= start:
            if slave:
                slave.reset()
            start = time.perf_counter_ns()
            end = start + int(seconds * 1e9)
        if end is not None and now >= end:
            break
        c.send()
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
    if slave:
        slave.collect(run)
    return run


def tcp_floor(exe: str, warmup: float, seconds: float) -> Run:
    """The same idle-line client against simline's Modbus TCP server, which answers at once:
    what a TCP round trip costs this client on this host, gateway or not."""
    proc = subprocess.Popen([exe, "tcp"], stdout=subprocess.PIPE, text=True)
    try:
        port = int(proc.stdout.readline().split()[1])
        return run_idle_client(port, None, 1750, warmup, seconds)
    finally:
        proc.kill()
        proc.wait()


class Relay:
    """simline relay on device: the least gateway, for the host's floor of added latency."""

    def __init__(self, exe: str, device: str) -> None:
        self.proc = subprocess.Popen([exe, "relay", device], stdout=subprocess.PIPE, text=True)
        self.port = int(self.proc.stdout.readline().split()[1])

    def stop(self) -> None:
        self.proc.kill()
        self.proc.wait()


def merge(name: str, parts: list) -> Run:
    run = Run(name)
    for p in parts:
        run.count += p.count
        run.seconds += p.seconds
        run.errors += p.errors
        run.collisions += p.collisions
        run.bad_frames += p.bad_frames
        run.latencies += p.latencies
        run.gaps += p.gaps
        run.held += p.held
        run.timed += p.timed
        run.cycles += p.cycles
    for values in (run.latencies, run.gaps, run.held, run.timed, run.cycles):
        values.sort()
    return run


def run_idle_rounds(exe: str, line: "Line", sides: dict, gateway_port: int, relay_port: int,
                    rounds: int, seconds: float) -> None:
    """The idle-line pace for the direct master, the relay and the gateway, taking turns, so
    that a change in the host's mood during the run weighs on all three alike."""
    pause_us = round(IDLE_EXTRA_S * 1e6)
    parts = {"direct": [], "relay": [], "gateway": []}
    for _ in range(rounds):
        direct = sides["direct"]
        parts["direct"].append(run_direct(exe, direct.device, direct.slave, line.t35, seconds,
                                          pause_us))
        parts["relay"].append(run_idle_client(relay_port, sides["relay"].slave, line.t35,
                                              0.05, seconds))
        parts["gateway"].append(run_idle_client(gateway_port, sides["gateway"].slave,
                                                line.t35, 0.05, seconds))
    line.idle_direct = merge("direct master, idle line", parts["direct"])
    line.idle_relay = merge("least gateway, idle line", parts["relay"])
    line.idle = merge("gateway, 1 client, idle line", parts["gateway"])


class Side:
    """A simulated slave, on a pty of its own or behind a socat pair; device: the master's end."""

    def __init__(self, exe: str, tmp: Path, use_socat: bool, baud: int,
                 dying: tuple[int, int] | None = None) -> None:
        self.pair = PtyPair(Path(tempfile.mkdtemp(dir=tmp))) if use_socat else None
        self.slave = Slave(exe, self.pair.device if self.pair else None, baud, dying)
        self.device = self.pair.gateway if self.pair else self.slave.device

    def stop(self) -> None:
        self.slave.stop()
        if self.pair:
            self.pair.stop()


# ------------------------------------------------------------------------ one line setting

@dataclass
class Line:
    title: str
    baud: int            # the gateway's --baudrate (sets its t3.5)
    paced: bool          # the slave takes the wire time to answer
    seconds: float
    runs: list = field(default_factory=list)
    idle: Run | None = None              # the gateway's idle-line client
    idle_direct: Run | None = None       # the direct master at the same pace
    idle_relay: Run | None = None        # the least gateway at the same pace
    slave_policy: str = "?"

    @property
    def t35(self) -> int:
        return t35_us(self.baud)

    @property
    def direct(self) -> Run:
        return self.runs[0]


def measure(line: Line, exe: str, tmp: Path, use_socat: bool, warmup: float,
            rounds: int, slice_s: float) -> None:
    baud = line.baud if line.paced else 0
    sides = {}
    gateway = relay = None
    try:
        for name in ("direct", "gateway", "relay"):
            sides[name] = Side(exe, tmp, use_socat, baud)
        line.slave_policy = sides["gateway"].slave.policy
        # the closed-loop reference on the very slave the gateway then uses
        same = sides["gateway"]
        line.runs.append(run_direct(exe, same.device, same.slave, line.t35, line.seconds))
        gateway = Gateway(tmp, sides["gateway"].device, "--baudrate", str(line.baud),
                          "--stout", "1000", "--max-connections", str(max(CLIENT_COUNTS) + 8),
                          "--log-level", "warning")
        for n in CLIENT_COUNTS:
            line.runs.append(run_clients(gateway.port, n, sides["gateway"].slave, warmup,
                                         line.seconds))
        relay = Relay(exe, sides["relay"].device)
        run_idle_rounds(exe, line, sides, gateway.port, relay.port, rounds, slice_s)
    finally:
        if relay is not None:
            relay.stop()
        if gateway is not None:
            rc = gateway.stop()
            log = gateway.log_path.read_text().strip()
            if log or rc:
                print(f"  gateway exit status {rc}; its log:\n    " + log.replace("\n", "\n    "))
        for side in sides.values():
            side.stop()


# ------------------------------------------------------------------------ report

def _share(r: Run, d: Run) -> float:
    return 100 * r.rate / d.rate


def _median_share(r: Run, d: Run) -> float:
    return 100 * d.median_cycle_us / r.median_cycle_us


def _added_us(line: Line, q: float = 50, run: str = "idle") -> float:
    """What the gateway (or the relay) adds at the idle-line pace, at percentile q."""
    return (getattr(line, run).lat_ms(q) - line.idle_direct.lat_ms(q)) * 1000


def report_line(line: Line) -> None:
    d = line.direct
    if line.paced:
        head = (f"{line.title}: slave answers after the wire time, "
                f"{wire_us(line.baud):.0f} us a transaction ({REQUEST_LEN}+{REPLY_LEN} chars x "
                f"{CHAR_BITS} bits)")
    else:
        head = (f"{line.title}: slave answers at once; gateway at --baudrate {line.baud}, so its "
                f"estimate of a request's time on the wire "
                f"({(REQUEST_LEN * CHAR_BITS * 1e6 / line.baud):.0f} us) never holds the line")
    print(f"\n{head}\n  t3.5 {line.t35} us; {line.seconds:g} s a run; slave "
          f"{'SCHED_FIFO' if line.slave_policy == 'fifo' else 'not real-time (SCHED_OTHER)'}")
    print(f"  {'':28} {'tx/s':>6} {'of':>6} {'cycle':>6} {'of':>6} {'lat':>7} {'lat':>7} "
          f"{'ideal':>7} {'gap':>5} {'gap':>5} {'gaps':>9}")
    print(f"  {'':28} {'':>6} {'direct':>6} {'p50':>6} {'direct':>6} {'p50':>7} {'p99':>7} "
          f"{'lat':>7} {'min':>5} {'p50':>5} {'< t3.5':>9}")
    print(f"  {'':28} {'':>6} {'%':>6} {'us':>6} {'%':>6} {'ms':>7} {'ms':>7} "
          f"{'ms':>7} {'us':>5} {'us':>5} {'':>9}")
    idle_runs = [line.idle_direct, line.idle_relay, line.idle]
    for i, r in enumerate(line.runs + idle_runs):
        below = f"{r.gaps_below(line.t35)}/{r.gap_count}"
        if any(r is x for x in idle_runs):
            rate = f"{'-':>6} {'-':>6} {'-':>6} {'-':>6}"
            ideal = line.idle_direct.lat_ms(50)     # one transaction of the direct master
        else:
            rate = (f"{r.rate:6.1f} {_share(r, d):6.1f} {r.median_cycle_us:6.0f} "
                    f"{_median_share(r, d):6.1f}")
            # k closed-loop clients on one line: each waits k cycles of the direct master
            ideal = (CLIENT_COUNTS[i - 1] if i else 1) * d.cycle_us / 1000
        print(f"  {r.name:28} {rate} {r.lat_ms(50):7.3f} {r.lat_ms(99):7.3f} {ideal:7.3f} "
              f"{r.gap_us(0):5.0f} {r.gap_us(50):5.0f} {below:>9}")
    print(f"  added latency, 1 client on an idle line: p50 {_added_us(line):+.0f} us, "
          f"p99 {_added_us(line, 99):+.0f} us; the least gateway adds p50 "
          f"{_added_us(line, 50, 'idle_relay'):+.0f} us, p99 "
          f"{_added_us(line, 99, 'idle_relay'):+.0f} us (this host's floor)")
    gw = line.runs[-1]
    print(f"  line saturated (32 clients): the gateway's median cycle is "
          f"{gw.median_cycle_us - d.median_cycle_us:+.0f} us over the direct master's "
          f"(mean {gw.cycle_us - d.cycle_us:+.0f} us); its median gap "
          f"{gw.gap_us(50) - d.gap_us(50):+.0f} us")
    for r in line.runs + idle_runs:
        if r.errors or r.collisions or r.bad_frames:
            print(f"  !! {r.name}: {r.errors} failed transactions, {r.collisions} requests over a "
                  f"reply, {r.bad_frames} bad frames at the slave")
        unsure = r.gaps_unsure(line.t35)
        if unsure:
            g, w = unsure[0]
            print(f"  !! {r.name}: {len(unsure)} gap(s) of unknown length around t3.5, e.g. "
                  f"{g / 1000:.0f}..{(g + w) / 1000:.0f} us: the slave was held up "
                  f"{w / 1000:.0f} us writing the reply before it")
    held = sum(len(r.held) for r in line.runs + idle_runs)
    if held:
        total = sum(r.gap_count for r in line.runs + idle_runs)
        print(f"  ({held} of {total} gaps left out of min/p50: the slave was held up "
              f"> {HELD_WRITE_NS // 1000} us writing the reply before them)")


def summary(lines: list) -> None:
    print("\nAgainst the issue's targets (figures only; mbusd for reference: 75 % of direct at "
          "115200, ~1 ms added)")
    print(f"  {'':16} {'rate of direct, 1/5/32 clients':>31} {'':>18} {'smallest':>9} "
          f"{'':>5} {'added':>8} {'floor':>6}")
    print(f"  {'':16} {'counted':>31} {'median cycles':>18} {'gap us':>9} "
          f"{'t3.5':>5} {'p50 us':>8} {'p50 us':>6}")
    for line in lines:
        d = line.direct
        counted = " / ".join(f"{_share(r, d):.1f}" for r in line.runs[1:])
        median = " / ".join(f"{_median_share(r, d):.1f}" for r in line.runs[1:])
        gap = min(r.gap_us(0) for r in line.runs[1:] + [line.idle])
        below = sum(r.gaps_below(line.t35) for r in line.runs[1:] + [line.idle])
        unsure = sum(len(r.gaps_unsure(line.t35)) for r in line.runs[1:] + [line.idle])
        gap_text = (f"{gap:.0f}" + (f" ({below} < t3.5)" if below else "")
                    + (f" ({unsure} unsure)" if unsure else ""))
        print(f"  {line.title:16} {counted + ' %':>31} {median + ' %':>18} {gap_text:>9} "
              f"{line.t35:5d} {_added_us(line):+8.0f} {_added_us(line, 50, 'idle_relay'):+6.0f}")
    print(f"  {'target':16} {f'>= {TARGET_RATE:g} % at line speed':>31} {'':>18} "
          f"{'>= t3.5':>9} {'':5} {f'<= {TARGET_ADDED_US:.0f}':>8}")
    print("  (floor: what the least gateway -- C, one thread, no checks -- adds on this host)")


# ------------------------------------------------------------------------ fairness (--fairness)

DEAD_UNIT = 9                  # no slave answers it (simline serves unit 1 only)
DEAD_BAUD = 19200
DEAD_STOUT_MS = 600
DEAD_CLIENTS = 4               # closed-loop clients of unit 1 beside the dead unit's one
SPREAD_COUNTS = (5, 32)
TARGET_DEAD_SHARE = 98.0       # % of the unit-1 rate alone kept beside the dead unit (issue 29)
TARGET_SPREAD = 2.0            # % between the most and the least served client
SPREAD_MIN_TX = 60             # transactions each, so that one more or less is under 2 %
# Demotion of silent devices (issue 13), when the gateway has it: off, and at its defaults.
DEMOTION_OPTIONS = ("--down-after", "--probe-interval")
WITHOUT_DEMOTION = ("--down-after", "0")
WITH_DEMOTION = ("--down-after", "3", "--probe-interval", "5000")   # the defaults
# Issue 29: a unit that answered before it died, so that its probes wait its learnt time
# (a unit that never answered is probed with its stout): its first reads answered, then none.
DIED_AFTER = 10
DIED_WARMUP_S = 6.0            # its answers, then down-after timeouts, before the window
DOWN_SETTLE_S = 1.0            # with demotion the window begins once it is down this long


def gateway_accepts(*options: str) -> bool:
    """Whether the gateway's `slave --help` lists every one of options."""
    text = subprocess.run([*GATEWAY_COMMAND, "--help"], capture_output=True,
                          text=True).stdout
    return all(re.search(rf"(^|\s){re.escape(o)}\b", text, re.M) for o in options)


@dataclass
class DeadUnitCase:
    title: str
    options: tuple             # the gateway's demotion options
    alone: Run                 # the unit-1 clients without the dead unit's client
    beside: Run                # the same with it
    # with demotion: the dead unit's probe timeout at the end (status), ms; the window began
    # once it was down (beside.ready), so its frames in the window are its probes
    probe_timeout_ms: float | None = None

    @property
    def probe_hold_ms(self) -> float:
        """What one probe holds the line: its request, its timeout, t3.5 after."""
        assert self.probe_timeout_ms is not None
        return (REQUEST_LEN * CHAR_BITS * 1e3 / DEAD_BAUD + self.probe_timeout_ms
                + t35_us(DEAD_BAUD) / 1e3)

    @property
    def share(self) -> float:
        return _share(self.beside, self.alone)

    @property
    def round_ms(self) -> float:
        """The line's own cycle for these clients: each request's median latency alone,
        one transaction of each of them."""
        return self.alone.lat_ms(50)

    @property
    def over_round_ms(self) -> float:
        """How much longer than that round the slowest unit-1 request took beside the
        dead unit (target: at most one stout)."""
        return self.beside.lat_ms(100) - self.round_ms


def measure_dead_unit(exe: str, tmp: Path, use_socat: bool, warmup: float,
                      seconds: float, died: bool = False) -> list[DeadUnitCase]:
    """The dead-unit case, on a gateway of its own for each demotion setting the gateway
    knows (none before issue 13's demotion: the run is then without it); died: also with a
    unit 9 that answered its first DIED_AFTER reads (issue 29)."""
    variants: list[tuple[str, tuple, tuple[int, int] | None]] = [("without demotion", (), None)]
    if gateway_accepts(*DEMOTION_OPTIONS):
        variants = [("without demotion", WITHOUT_DEMOTION, None),
                    ("with demotion", WITH_DEMOTION, None)]
        if died:
            variants.append((f"died after {DIED_AFTER} answers", WITH_DEMOTION,
                             (DEAD_UNIT, DIED_AFTER)))
    cases = []
    for title, options, dying in variants:
        side = Side(exe, tmp, use_socat, DEAD_BAUD, dying)
        gateway = None
        try:
            gateway = Gateway(tmp, side.device, "--baudrate", str(DEAD_BAUD), "--stout",
                              str(DEAD_STOUT_MS), "--exception", "--max-connections", "40",
                              "--log-level", "warning", *options)
            demoted = options not in ((), WITHOUT_DEMOTION)
            alone = run_clients(gateway.port, DEAD_CLIENTS, side.slave, warmup, seconds)
            beside = run_clients(gateway.port, DEAD_CLIENTS, side.slave,
                                 DIED_WARMUP_S if dying else warmup, seconds,
                                 others=1, other_unit=DEAD_UNIT,
                                 ready=_down(gateway) if demoted else None)
            case = DeadUnitCase(title, options, alone, beside)
            dead = gateway.device(DEAD_UNIT) if demoted else None
            if dead is not None:
                case.probe_timeout_ms = dead.get("probe_timeout_ms")
            cases.append(case)
        finally:
            if gateway is not None:
                _stop_and_show(gateway)
            side.stop()
    return cases


def _down(gateway: Gateway) -> Callable[[], bool]:
    """Whether the gateway has had the dead unit down for DOWN_SETTLE_S (the unit-1 requests
    queued behind its last timeout served: none of them is timed in the window)."""
    def down() -> bool:
        dead = gateway.device(DEAD_UNIT)
        return dead is not None and dead["health"] == "down" and \
            time.time() - dead["health_since"] >= DOWN_SETTLE_S
    return down


def measure_spread(line: Line, exe: str, tmp: Path, use_socat: bool, warmup: float) -> None:
    """Closed-loop clients (SPREAD_COUNTS of them) on a gateway as the main runs start it."""
    side = Side(exe, tmp, use_socat, line.baud if line.paced else 0)
    gateway = None
    try:
        gateway = Gateway(tmp, side.device, "--baudrate", str(line.baud), "--stout", "1000",
                          "--max-connections", str(max(SPREAD_COUNTS) + 8),
                          "--log-level", "warning")
        for n in SPREAD_COUNTS:
            line.runs.append(run_clients(gateway.port, n, side.slave, warmup,
                                         spread_seconds(line, n)))
    finally:
        if gateway is not None:
            _stop_and_show(gateway)
        side.stop()


def spread_seconds(line: Line, clients: int) -> float:
    """line.seconds, or longer when clients served in turn would not each get SPREAD_MIN_TX
    transactions in it: one transaction more or less must be below the spread's target."""
    cycle_s = wire_us(line.baud) / 1e6 if line.paced else 0.0
    cycle_s += line.t35 / 1e6
    return max(line.seconds, clients * SPREAD_MIN_TX * cycle_s) if line.seconds >= 10 \
        else line.seconds


def _stop_and_show(gateway: Gateway) -> None:
    rc = gateway.stop()
    log = gateway.log_path.read_text().strip()
    if log or rc:
        print(f"  gateway exit status {rc}; its log:\n    " + log.replace("\n", "\n    "))


def spread_pct(run: Run) -> float:
    """How many fewer transactions the least served client had than the most served, in %
    of the most."""
    most, least = run.per_client[-1], run.per_client[0]
    return 100 * (most - least) / most if most else float("nan")


def report_dead_unit(cases: list[DeadUnitCase], seconds: float) -> None:
    print(f"\nDead unit: {DEAD_BAUD} baud 8N1, --stout {DEAD_STOUT_MS} --exception; "
          f"{DEAD_CLIENTS} closed-loop clients read unit {UNIT}, a fifth reads unit "
          f"{DEAD_UNIT}, which no slave answers (its 0x0B replies are not counted); "
          f"{seconds:g} s a run")
    print(f"  {'':44} {'unit-1':>7} {'of':>6} {'lat':>7} {'lat':>7} {'slowest':>8} "
          f"{'over':>7} {'unit-9':>7}")
    print(f"  {'':44} {'tx/s':>7} {'alone':>6} {'p50':>7} {'p99':>7} {'':>8} "
          f"{'round':>7} {'frames':>7}")
    print(f"  {'':44} {'':>7} {'%':>6} {'ms':>7} {'ms':>7} {'ms':>8} {'ms':>7} {'':>7}")
    for case in cases:
        for name, run in ((f"{case.title}: {DEAD_CLIENTS} clients alone", case.alone),
                          (f"{case.title}: and unit {DEAD_UNIT}'s client", case.beside)):
            beside = run is case.beside
            share = f"{case.share:6.1f}" if beside else f"{100.0:6.1f}"
            over = f"{case.over_round_ms:7.0f}" if beside else f"{'-':>7}"
            frames = f"{run.bad_frames:7d}" if beside else f"{'-':>7}"
            print(f"  {name:44} {run.rate:7.1f} {share} {run.lat_ms(50):7.1f} "
                  f"{run.lat_ms(99):7.1f} {run.lat_ms(100):8.1f} {over} {frames}")
            if run.errors or run.collisions:
                print(f"  !! {name}: {run.errors} failed transactions, {run.collisions} "
                      f"requests over a reply")
        options = f" ({' '.join(case.options)})" if case.options else ""
        print(f"  {case.title}{options}: the line's own cycle for {DEAD_CLIENTS} clients "
              f"(their p50 alone) {case.round_ms:.1f} ms; the slowest unit-1 request beside "
              f"unit {DEAD_UNIT} took {case.over_round_ms:.0f} ms more (target: <= one "
              f"stout, {DEAD_STOUT_MS} ms)")
        if case.probe_timeout_ms is not None:
            report_probes(case, seconds)
    print("  (unit-9 frames: the requests for unit 9 the slave saw on the line; of alone: "
          f"target >= {TARGET_DEAD_SHARE:g} % with demotion)")


def report_probes(case: DeadUnitCase, seconds: float) -> None:
    """The dead unit's probes in the window, and what they cost the line."""
    if not case.beside.ready:
        print(f"  !! {case.title}: unit {DEAD_UNIT} was not down within {READY_LIMIT_S:g} s "
              f"of the warm-up: its frames in the window are not all probes")
    probes, hold = case.beside.bad_frames, case.probe_hold_ms
    print(f"  {case.title}: {probes} probes of unit {DEAD_UNIT} in the {seconds:g} s (down "
          f"throughout), each holding the line {hold:.1f} ms (request, probe timeout "
          f"{case.probe_timeout_ms:.1f} ms, t3.5): {100 * probes * hold / 1000 / seconds:.2f} "
          f"% of the line; the slowest unit-1 request {case.over_round_ms:.0f} ms over the "
          f"round (behind one probe: up to {hold:.0f} ms more)")


def report_spread(lines: list[Line]) -> None:
    print(f"\nPer-client spread: closed-loop clients, transactions each in the window "
          f"(target: the least served within {TARGET_SPREAD:g} % of the most)")
    print(f"  {'':16} {'clients':>7} {'s':>4} {'tx/s':>7} {'least':>6} {'most':>6} "
          f"{'spread':>7} {'1 tx':>6}")
    print(f"  {'':16} {'':>7} {'':>4} {'':>7} {'':>6} {'':>6} {'%':>7} {'%':>6}")
    for line in lines:
        for n, run in zip(SPREAD_COUNTS, line.runs, strict=True):
            one = 100 / run.per_client[-1] if run.per_client[-1] else float("nan")
            print(f"  {line.title:16} {n:7d} {spread_seconds(line, n):4.0f} {run.rate:7.1f} "
                  f"{run.per_client[0]:6d} {run.per_client[-1]:6d} {spread_pct(run):7.2f} "
                  f"{one:6.2f}")
            if run.errors or run.collisions or run.bad_frames:
                print(f"  !! {run.errors} failed transactions, {run.collisions} requests over "
                      f"a reply, {run.bad_frames} bad frames at the slave")
    print("  (1 tx: what one transaction more or less is, in % of the most served: the "
          "resolution of the spread)")


def fairness(args, tmp: Path, exe: str) -> None:
    quick = args.quick
    dead_warmup, dead_s = (2.5, 3.0) if quick else (3.0, 10.0)
    if args.dead_seconds:              # the dead unit alone, over a window of its own
        report_dead_unit(measure_dead_unit(exe, tmp, args.socat, dead_warmup,
                                           args.dead_seconds, died=True), args.dead_seconds)
        return
    spread_s = {19200: 3.0, 115200: 2.0, 0: 2.0} if quick else {19200: 20.0, 115200: 10.0,
                                                               0: 10.0}
    report_dead_unit(measure_dead_unit(exe, tmp, args.socat, dead_warmup, dead_s), dead_s)
    lines = [Line("19200 baud", 19200, True, spread_s[19200]),
             Line("115200 baud", 115200, True, spread_s[115200]),
             Line("full-speed pty", 4000000, False, spread_s[0])]
    for line in lines:
        measure_spread(line, exe, tmp, args.socat, 0.3)
    report_spread(lines)


@contextmanager
def pymodbus_line(tmp: Path, unit: int) -> Iterator[PtyPair]:
    """A socat pty pair with pymodbus's RTU slave `unit` on its far end; yields the pair."""
    pair = PtyPair(tmp)
    try:
        peer = Peer("pymodbus_slave.py", pair.device, str(unit))
        try:
            yield pair
        finally:
            peer.stop()
    finally:
        pair.stop()


def quick_main(doc: str, run: Callable[[bool], None], quick_help: str) -> None:
    """A bench script's command line: its --quick, then run(quick)."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help=quick_help)
    run(ap.parse_args().quick)


def _loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "?"


# The benchmarks main() runs instead of its own: bench/NAME.py, beside this script, each
# with a run(quick).
OTHER_BENCHES = {
    "table": "the exchange table as a Modbus TCP server beside libmodbus's and pymodbus's "
             "(bench/table.py; about 130 s; --quick: 40 s)",
    "tls": "Modbus/TCP Security's handshakes/s and latency added per request over plain TCP "
           "(bench/tls.py; about 25 s)",
    "scenarios": "100 serial scenarios saturating the line, a client beside them, one "
                 "scenario's period (bench/scenarios.py; about 70 s; --quick: 25 s)",
    "lines": "8 lines at 115200 through one listener, and the serial-to-serial bridge's added "
             "latency (bench/lines.py; about 45 s; --quick: 15 s)",
    "mqtt": "northbound MQTT's cost, 10,000 metric changes/s, MQTT off and on in turns "
            "(bench/mqtt.py; about 90 s; --quick: 20 s)",
    "cache": "the read cache's line transactions per request and its hits over loopback "
             "beside the table's server (bench/cache.py; about 60 s; --quick: 20 s)",
    "web": "a client's latency with a browser on the web console's Traffic page and without "
           "(bench/web.py; about 40 s)",
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs (under 30 s in all)")
    ap.add_argument("--socat", action="store_true",
                    help="put the line on a socat pty pair (as the tests do) instead of one pty")
    ap.add_argument("--fairness", action="store_true",
                    help="instead of the runs above: a dead unit beside closed-loop clients, "
                    "and the per-client spread of transactions (about 110 s; --quick: 30 s)")
    ap.add_argument("--dead-seconds", type=float, default=0,
                    help="with --fairness: only the dead unit, each run this long (issue "
                    "29's figure: 60), a unit that answered before it died too (about "
                    "6 x (4 + this) s)")
    for name, what in OTHER_BENCHES.items():
        ap.add_argument(f"--{name}", action="store_true",
                        help=f"instead of the runs above: {what}")
    args = ap.parse_args()
    for name in OTHER_BENCHES:
        if getattr(args, name):
            importlib.import_module(name).run(args.quick)
            return
    if args.quick:
        secs, warmup, rounds, slice_s = {19200: 1.5, 115200: 1.0, 0: 1.0}, 0.2, 3, 0.4
    else:
        secs, warmup, rounds, slice_s = {19200: 8.0, 115200: 5.0, 0: 4.0}, 0.3, 8, 0.8
    lines = [Line("19200 baud", 19200, True, secs[19200]),
             Line("115200 baud", 115200, True, secs[115200]),
             Line("full-speed pty", 4000000, False, secs[0])]
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
    print(f"  load average before: {_loadavg()} (anything else running skews the figures)")
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-") as tmp:
        tmp = Path(tmp)
        exe = build_simline(tmp)
        if args.fairness:
            fairness(args, tmp, exe)
            print(f"\n({time.monotonic() - began:.0f} s; load average after: {_loadavg()})")
            return
        floor = tcp_floor(exe, warmup, 0.5 if args.quick else 1.0)
        print(f"  TCP floor: this client against a C Modbus TCP server on loopback that answers "
              f"at once: p50 {floor.lat_ms(50) * 1000:.0f} us, "
              f"p99 {floor.lat_ms(99) * 1000:.0f} us "
              f"(part of any gateway's added latency)")
        for line in lines:
            measure(line, exe, tmp, args.socat, warmup, rounds, slice_s)
            report_line(line)
    summary(lines)
    print(f"\n({time.monotonic() - began:.0f} s; load average after: {_loadavg()})")


if __name__ == "__main__":
    main()
