#!/usr/bin/env python3
"""The exchange table's row (issue 14): mbgw as a Modbus TCP server of its own data, beside
libmodbus's and pymodbus's servers.  Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py --table [--quick]      (or bench/table.py [--quick])

FC03 reads of 10 and 125 registers from address 0, by 1, 5 and 32 clients, each a closed loop
over its own TCP connection on loopback (bench/tableload.c, C, one epoll thread, built at run
time).  Servers, each measured in the same run:

  * raw: tableload's own server (C, epoll, answers zeros, checks nothing): the ceiling of this
    load generator on this host, to show the generator is not what limits the others;
  * libmodbus: bench/libmodbus_server.c, select() + modbus_receive + modbus_reply over a
    modbus_mapping_new of 65536 registers (Debian's libmodbus, built at run time);
  * pymodbus: bench/pymodbus_server.py, the venv's pinned pymodbus, asyncio;
  * mbgw slave: `mbgw slave --table --no-direct` on a socat pty nobody answers: every unit
    id reaches the table;
  * mbgw master: `mbgw master --table --table-port P`, the table served on its own port.

Columns: requests/s over the window, p50/p99 latency (request sent -> whole reply read, at the
client), the server's CPU time per request (every thread of it, from /proc/PID/task/*/schedstat
at the window's ends) and the generator's CPU time in % of the window (one thread: near 100 %
would mean the generator, not the server, is the limit).  See README.md, "The exchange table".
"""
import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from array import array
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from tests.harness import Gateway, PtyPair, free_port, stop  # noqa: E402

REGISTER_COUNTS = (10, 125)
CLIENT_COUNTS = (1, 5, 32)
UNIT = 1
MAX_CONNECTIONS = max(CLIENT_COUNTS) + 8
READY_TIMEOUT_S = 15.0
# The issue's aim, in throughput: mbgw above pymodbus, and within 2x of libmodbus's C server.
AIM_OF_LIBMODBUS = 50.0


@dataclass
class TableRun:
    """One server under one load (registers, clients), pooled over the rounds."""
    server: str
    registers: int
    clients: int
    count: int = 0
    errors: int = 0
    window_ns: int = 0
    generator_cpu_us: int = 0
    server_cpu_ns: int = 0
    spread: float = 0.0            # the largest (most - least) / most of a round, in %
    latencies: array = field(default_factory=lambda: array("Q"))    # ns, sorted at the end

    def add(self, result: list[int], latencies: array, server_cpu_ns: int) -> None:
        count, errors, window, _, _, _, user, system, least, most = result
        self.count += count
        self.errors += errors
        self.window_ns += window
        self.generator_cpu_us += user + system
        self.server_cpu_ns += server_cpu_ns
        if most:
            self.spread = max(self.spread, 100 * (most - least) / most)
        self.latencies.extend(latencies)

    @property
    def rate(self) -> float:
        return self.count / (self.window_ns / 1e9) if self.window_ns else 0.0

    def latency_us(self, q: float) -> float:
        """Nearest-rank percentile (q in 0..100) of the latencies, once sorted."""
        if not self.latencies:
            return float("nan")
        rank = max(1, math.ceil(q / 100 * len(self.latencies)))
        return self.latencies[min(rank, len(self.latencies)) - 1] / 1e3

    @property
    def server_us_per_request(self) -> float:
        return self.server_cpu_ns / 1e3 / self.count if self.count else float("nan")

    @property
    def generator_pct(self) -> float:
        return 100 * self.generator_cpu_us * 1e3 / self.window_ns if self.window_ns else 0.0


# ------------------------------------------------------------------------ building

def compiler() -> str:
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        sys.exit("bench: no C compiler (cc) to build bench/tableload.c")
    return cc


def build(directory: Path) -> tuple[str, str | None]:
    """tableload, and the libmodbus server (None, said why, when libmodbus does not build)."""
    cc = compiler()
    load = directory / "tableload"
    subprocess.run([cc, "-O2", "-Wall", "-o", str(load), str(HERE / "tableload.c")], check=True)
    server = directory / "libmodbus_server"
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"], capture_output=True,
                           text=True)
    built = subprocess.run([cc, "-O2", "-Wall", "-o", str(server), str(HERE / "libmodbus_server.c"),
                            *(flags.stdout.split() or ["-I/usr/include/modbus", "-lmodbus"])],
                           capture_output=True, text=True)
    if built.returncode:
        print(f"  libmodbus server not built (libmodbus-dev missing?): {built.stderr.strip()}")
        return str(load), None
    return str(load), str(server)


# ------------------------------------------------------------------------ servers

def cpu_ns(pid: int) -> int:
    """CPU time of every thread of pid so far, in ns (schedstat: exact, unlike the ticks of
    /proc/PID/stat)."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            total += int((task / "schedstat").read_text().split()[0])
        except (OSError, IndexError, ValueError):
            pass                 # a thread that ended meanwhile
    return total


class Process:
    """A server that prints READY when it listens on 127.0.0.1:port."""

    def __init__(self, name: str, command: list[str], port: int) -> None:
        self.name = name
        self.port = port
        self.proc = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline()
        if not line.startswith("READY"):
            stop(self.proc)
            raise RuntimeError(f"{name} did not start: {line!r}")

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stop(self) -> None:
        stop(self.proc)


def listening(name: str, *command: str) -> Process:
    """command, with a free port as its last argument."""
    port = free_port()
    return Process(name, [*command, str(port)], port)


class MbgwServer:
    """mbgw on a socat pty pair that nobody answers, its table reached on 127.0.0.1:port."""

    def __init__(self, name: str, tmp: Path, mode: str) -> None:
        self.name = name
        directory = Path(tempfile.mkdtemp(dir=tmp))
        self.pair = PtyPair(directory)
        common = ("--baudrate", "115200", "--log-level", "warning")
        try:
            if mode == "slave":
                self.gateway = Gateway(directory, self.pair.gateway, *common, "--table",
                                       "--no-direct", "--max-connections", str(MAX_CONNECTIONS))
                self.port = self.gateway.port
            else:
                self.port = free_port()
                self.gateway = Gateway(directory, self.pair.gateway, *common, "--table",
                                       "--table-port", str(self.port), *MASTER_OPTIONS,
                                       mode="master", listen=False, port=self.port)
        except BaseException:
            self.pair.stop()
            raise

    @property
    def pid(self) -> int:
        return self.gateway.proc.pid

    def stop(self) -> None:
        rc = self.gateway.stop()
        if rc:
            print(f"  {self.name}: exit status {rc}; its log:\n    "
                  + self.gateway.log().strip().replace("\n", "\n    "))
        self.pair.stop()


# Master mode's table server: where it listens and how many clients it takes, when the
# gateway has options for them (filled in by master_options()).
MASTER_OPTIONS: list[str] = []


def master_options() -> list[str]:
    text = subprocess.run([sys.executable, "-m", "mbgw", "master", "--help"], capture_output=True,
                          text=True, cwd=ROOT).stdout
    options = []
    if "--table-bind" in text:
        options += ["--table-bind", "127.0.0.1"]
    if "--table-max-connections" in text:
        options += ["--table-max-connections", str(MAX_CONNECTIONS)]
    return options


def mbgw_has_table() -> bool:
    text = subprocess.run([sys.executable, "-m", "mbgw", "slave", "--help"], capture_output=True,
                          text=True, cwd=ROOT).stdout
    return "--table" in text and "--no-direct" in text


# ------------------------------------------------------------------------ the load

def socket_count(pid: int) -> int:
    count = 0
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            count += os.readlink(fd).startswith("socket:")
        except OSError:
            pass                 # closed meanwhile
    return count


def settle(server, sockets: int, limit_s: float = 2.0) -> None:
    """Until the server has closed the last run's connections (back to `sockets`, its count
    when idle), at most limit_s: a server at its connection limit would refuse the next run's."""
    deadline = time.monotonic() + limit_s
    while socket_count(server.pid) > sockets and time.monotonic() < deadline:
        time.sleep(0.005)


def run_load(load: str, server, run: TableRun, warmup: float, seconds: float,
             latency_file: Path) -> None:
    """One closed-loop run against server, added to run."""
    proc = subprocess.Popen([load, "client", str(server.port), str(run.clients),
                             str(run.registers), str(UNIT), str(warmup), str(seconds),
                             str(latency_file)], stdout=subprocess.PIPE, text=True)
    cpu_start = cpu_end = 0
    result = None
    for line in proc.stdout:
        if line.startswith("START"):
            cpu_start = cpu_ns(server.pid)
        elif line.startswith("END"):
            cpu_end = cpu_ns(server.pid)
        elif line.startswith("RESULT"):
            result = [int(v) for v in line.split()[1:]]
    if proc.wait() or result is None:
        raise RuntimeError(f"tableload against {server.name} failed ({proc.returncode})")
    latencies = array("Q")
    latencies.frombytes(latency_file.read_bytes())
    run.add(result, latencies, cpu_end - cpu_start)


def measure(servers: list, load: str, tmp: Path, rounds: int, warmup: float,
            seconds: float) -> list[TableRun]:
    """Every load against every server, in rounds: within a round each server in turn, so
    that a change in the host's mood (this VM's wake-up costs drift within seconds) weighs
    on all of them alike."""
    idle = {server.name: socket_count(server.pid) for server in servers}
    runs = []
    latency_file = tmp / "latencies"
    for registers in REGISTER_COUNTS:
        for clients in CLIENT_COUNTS:
            case = [TableRun(server.name, registers, clients) for server in servers]
            for _ in range(rounds):
                for server, run in zip(servers, case, strict=True):
                    settle(server, idle[server.name])
                    run_load(load, server, run, warmup, seconds, latency_file)
            for run in case:
                run.latencies = array("Q", sorted(run.latencies))
            runs += case
    return runs


# ------------------------------------------------------------------------ report

def report(runs: list[TableRun], rounds: int, seconds: float) -> None:
    by = {(r.server, r.registers, r.clients): r for r in runs}
    print(f"\n  {'server':12} {'regs':>4} {'clients':>7} {'req/s':>8} {'of':>6} {'p50':>7} "
          f"{'p99':>7} {'server':>7} {'gen':>5} {'spread':>7}")
    print(f"  {'':12} {'':>4} {'':>7} {'':>8} {'libmb':>6} {'us':>7} {'us':>7} "
          f"{'us/req':>7} {'CPU':>5} {'':>7}")
    print(f"  {'':12} {'':>4} {'':>7} {'':>8} {'%':>6} {'':>7} {'':>7} {'':>7} {'%':>5} "
          f"{'%':>7}")
    for r in sorted(runs, key=lambda r: (r.registers, r.clients)):
        ref = by.get(("libmodbus", r.registers, r.clients))
        of = f"{100 * r.rate / ref.rate:6.0f}" if ref and ref.rate else f"{'-':>6}"
        spread = f"{r.spread:7.0f}" if r.clients > 1 else f"{'-':>7}"
        print(f"  {r.server:12} {r.registers:4d} {r.clients:7d} {r.rate:8.0f} {of} "
              f"{r.latency_us(50):7.0f} {r.latency_us(99):7.0f} "
              f"{r.server_us_per_request:7.1f} {r.generator_pct:5.0f} {spread}")
        if r.errors:
            print(f"  !! {r.server}: {r.errors} failed requests (exception, wrong reply or none)")
    print(f"  ({rounds} rounds of {seconds:g} s a run, the servers in turn within a round; "
          "server us/req: its CPU time, every thread, per request; gen CPU: the load "
          "generator's, one thread, in % of the window; spread: the largest gap between the "
          "most and the least served client of a round, in % of the most)")
    aims(by)


def aims(by: dict) -> None:
    mbgw = sorted({s for s, _, _ in by if s.startswith("mbgw")})
    if not mbgw:
        return
    print(f"\n  Against the issue's aim (throughput: above pymodbus, >= {AIM_OF_LIBMODBUS:g} % of "
          "libmodbus), 1 / 5 / 32 clients")
    for name in mbgw:
        for registers in REGISTER_COUNTS:
            of_lib, of_py = [], []
            for clients in CLIENT_COUNTS:
                r = by[(name, registers, clients)]
                lib = by.get(("libmodbus", registers, clients))
                py = by.get(("pymodbus", registers, clients))
                of_lib.append(f"{100 * r.rate / lib.rate:.0f}" if lib else "-")
                of_py.append(f"{r.rate / py.rate:.2f}" if py else "-")
            print(f"  {name:12} {registers:3d} regs: {' / '.join(of_lib):>14} % of libmodbus, "
                  f"{' / '.join(of_py):>18} x pymodbus")


def loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "?"


def start_servers(tmp: Path, load: str, libmodbus: str | None,
                  only: set[str] | None) -> list:
    starts = [("raw", lambda: listening("raw", load, "raw"))]
    if libmodbus:
        starts.append(("libmodbus", lambda: listening("libmodbus", libmodbus)))
    starts.append(("pymodbus", lambda: listening(
        "pymodbus", sys.executable, str(HERE / "pymodbus_server.py"))))
    if mbgw_has_table():
        MASTER_OPTIONS[:] = master_options()
        starts.append(("mbgw slave", lambda: MbgwServer("mbgw slave", tmp, "slave")))
        starts.append(("mbgw master", lambda: MbgwServer("mbgw master", tmp, "master")))
    else:
        print("  mbgw: no --table in this build; its rows are left out")
    servers: list = []
    try:
        for name, start in starts:
            if not only or name in only:
                servers.append(start())
    except BaseException:
        stop_servers(servers)
        raise
    return servers


def stop_servers(servers: list) -> None:
    for server in servers:
        server.stop()


def run(quick: bool, only: set[str] | None = None) -> None:
    rounds, warmup, seconds = (2, 0.1, 0.4) if quick else (5, 0.1, 0.6)
    print(f"mbgw bench, the exchange table: FC03 reads of {' and '.join(map(str, REGISTER_COUNTS))}"
          f" registers from address 0, {' / '.join(map(str, CLIENT_COUNTS))} closed-loop clients "
          "on loopback")
    print(f"  host: {os.cpu_count()} CPUs; load average before: {loadavg()} (anything else "
          "running skews the figures)")
    began = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-table-") as tmp_name:
        tmp = Path(tmp_name)
        load, libmodbus = build(tmp)
        servers = start_servers(tmp, load, libmodbus, only)
        try:
            runs = measure(servers, load, tmp, rounds, warmup, seconds)
        finally:
            stop_servers(servers)
    report(runs, rounds, seconds)
    print(f"\n({time.monotonic() - began:.0f} s; load average after: {loadavg()})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="2 rounds of 0.4 s runs instead of 5 rounds of 0.6 s")
    ap.add_argument("--only", action="append", metavar="SERVER",
                    help="measure only this server (raw, libmodbus, pymodbus, 'mbgw slave', "
                    "'mbgw master'); repeat for more")
    args = ap.parse_args()
    run(args.quick, set(args.only) if args.only else None)


if __name__ == "__main__":
    main()
