#!/usr/bin/env python3
"""Remote lines (issue 26): one Modbus TCP device that takes one client, shared.  Prints
figures, never pass/fail.

    .venv/bin/python bench/remote.py [--quick]
    .venv/bin/python bench/remote.py --versus OTHER-CHECKOUT [--quick]

The device is an emulator in a process of its own (this script, `--device`): one connection
at a time (a second one is reset), FC 03 answered after a fixed service time of 2 ms, the
reply under the request's transaction id.  Side by side, on loopback, in one run:

  * direct: a client connected to the device itself;
  * mbgw: `mbgw slave` whose line `inverter` is `connect = "modbus-tcp://..."` (line serial on
    a pty nobody answers on), unit 1 routed to it;
  * modbus-proxy 0.8.0 (PyPI; `pip install modbus-proxy==0.8.0`), bound to its own port.

Per gateway: the latency of one client's requests, one at a time (p50/p99, and what the
gateway adds over direct), and the rate of 1, 8 and 32 closed-loop clients (the device's
limit is 1 / 2 ms = 500 requests/s, less its own overhead).  Then wrong deliveries under late
replies: the device answers every 10th request 150 ms late; mbgw's stout and modbus-proxy's
timeout are 100 ms; 8 clients each read registers of their own, so a reply carrying another
client's registers is a wrong delivery (and the connections the device had to accept).

Last, RTU over TCP: bench.py's simulated slave (simline slave, answering after the wire time
of request and reply at 115200) on a pty that socat carries to a TCP listener, a serial
device server; mbgw's line `rtu-over-tcp://` to it, 8 closed-loop clients: the rate against
the serial line's own limit (wire time + t3.5 a transaction).  It needs a C compiler (cc)
for bench/simline.c.  See README.md, "Remote lines".
"""
import argparse
import os
import select
import selectors
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CHECKOUT = HERE.parent
SERVICE_S = 0.002
LATE_EVERY = 10
LATE_S = 0.150
TIMEOUT_MS = 100
HEADER = struct.Struct(">HHHB")


# --- the device (a process of its own) ---

def device(port: int, late: bool, tally: Path) -> None:
    """Serve until killed; tally: a file that says the connections accepted, and reset."""
    listener = socket.create_server(("127.0.0.1", port))
    listener.setblocking(False)
    selector = selectors.DefaultSelector()
    selector.register(listener, selectors.EVENT_READ)
    print("READY", flush=True)
    served = accepted = resets = 0
    conn: socket.socket | None = None
    buf = b""
    while True:
        for key, _ in selector.select():
            if key.fileobj is listener:
                new, _ = listener.accept()
                if conn is not None:        # one client: the second is reset
                    new.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                    new.close()
                    resets += 1
                else:
                    conn = new
                    accepted += 1
                tally.with_suffix(".new").write_text(f"{accepted} {resets}\n")
                os.replace(tally.with_suffix(".new"), tally)      # read whole, never half
                if conn is not new:
                    continue
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                selector.register(conn, selectors.EVENT_READ)
                continue
            assert conn is not None
            try:
                chunk = conn.recv(4096)
            except ConnectionResetError:
                chunk = b""
            if not chunk:
                selector.unregister(conn)
                conn.close()
                conn, buf = None, b""
                continue
            buf += chunk
            while len(buf) >= 12:
                tid, _, _, unit = HEADER.unpack_from(buf)
                start, count = struct.unpack_from(">HH", buf, 8)
                buf = buf[12:]
                served += 1
                time.sleep(LATE_S if late and served % LATE_EVERY == 0 else SERVICE_S)
                data = b"".join(struct.pack(">H", (start + i) & 0xFFFF) for i in range(count))
                conn.sendall(HEADER.pack(tid, 0, 3 + len(data), unit) + bytes((3, len(data)))
                             + data)


# --- the clients ---

def request(tid: int, start: int) -> bytes:
    return HEADER.pack(tid, 0, 6, 1) + struct.pack(">BHH", 3, start, 10)


def answers(reply: bytes, start: int) -> bool:
    return len(reply) == 29 and reply[7] == 3 and struct.unpack_from(">H", reply, 9)[0] == start


def connect(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def read_reply(sock: socket.socket) -> bytes:
    data = b""
    while len(data) < 6 or len(data) < 6 + struct.unpack_from(">H", data, 4)[0]:
        chunk = sock.recv(512)
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


def cpu_s(pid: int) -> float:
    """The CPU time (user + system, all threads) process pid has used so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def handover_floor(count: int) -> list[int]:
    """The reference floor of a thread crossing on this host, now: two Python threads
    waking each other through eventfds and poll() (the hand-over mbgw's face and a remote
    line's thread make), one round trip (two crossings) after each idle SERVICE_S, sorted
    ns."""
    there = os.eventfd(0, os.EFD_NONBLOCK)
    back = os.eventfd(0, os.EFD_NONBLOCK)

    def peer() -> None:
        waiting = select.poll()
        waiting.register(there, select.POLLIN)
        for _ in range(count):
            waiting.poll()
            os.eventfd_read(there)
            os.eventfd_write(back, 1)

    thread = threading.Thread(target=peer)
    thread.start()
    waiting = select.poll()
    waiting.register(back, select.POLLIN)
    out = []
    for _ in range(count):
        time.sleep(SERVICE_S)
        t0 = time.perf_counter_ns()
        os.eventfd_write(there, 1)
        waiting.poll()
        os.eventfd_read(back)
        out.append(time.perf_counter_ns() - t0)
    thread.join()
    os.close(there)
    os.close(back)
    return sorted(out)


def latencies(sock: socket.socket, count: int) -> list[int]:
    """count requests one at a time on sock: their round trips, ns."""
    out = []
    for tid in range(count):
        t0 = time.perf_counter_ns()
        sock.sendall(request(tid, tid % 100))
        read_reply(sock)
        out.append(time.perf_counter_ns() - t0)
    return out


def in_turn(served: dict[str, tuple[int, int]], count: int) -> tuple[dict, dict]:
    """Each contender (name: its port, the process whose CPU it is) answering one client in
    turn, a round of 100 requests each, so that all see the same load: each one's round
    trips (sorted ns) and CPU a request (us).  Each client keeps its one connection."""
    socks = {name: connect(port) for name, (port, _) in served.items()}
    lat: dict[str, list[int]] = {name: [] for name in served}
    cpu = dict.fromkeys(served, 0.0)
    try:
        for sock in socks.values():
            latencies(sock, 50)                     # warm-up, and the connection made
        for _ in range(count // 100):
            for name, (_, pid) in served.items():
                before = cpu_s(pid)
                lat[name] += latencies(socks[name], 100)
                cpu[name] += cpu_s(pid) - before
    finally:
        for sock in socks.values():
            sock.close()
    return ({name: sorted(values) for name, values in lat.items()},
            {name: used / count * 1e6 for name, used in cpu.items()})


def closed_loop(port: int, clients: int, seconds: float, timeout_s: float = 5.0) -> tuple:
    """clients closed-loop clients for seconds: (replies a second, wrong deliveries, no
    reply within timeout_s).  Client k reads registers 1000 k + n: another's is wrong."""
    selector = selectors.DefaultSelector()
    state = {}
    for k in range(clients):
        sock = connect(port)
        sock.setblocking(False)
        state[sock] = [k, 0, b"", time.monotonic()]
        sock.sendall(request(0, 1000 * k))
        selector.register(sock, selectors.EVENT_READ)
    done = wrong = lost = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end and state:
        for key, _ in selector.select(0.05):
            sock = key.fileobj
            k, n, buf, _ = entry = state[sock]
            try:
                chunk = sock.recv(512)
            except OSError:
                chunk = b""
            if not chunk:
                selector.unregister(sock)
                del state[sock]
                continue
            buf += chunk
            while len(buf) >= 6 and len(buf) >= 6 + struct.unpack_from(">H", buf, 4)[0]:
                size = 6 + struct.unpack_from(">H", buf, 4)[0]
                reply, buf = buf[:size], buf[size:]
                if reply[7] == 3 and not answers(reply, 1000 * k + n % 100):
                    wrong += 1
                done += 1
                n += 1
                entry[3] = time.monotonic()
                sock.sendall(request(n & 0xFFFF, 1000 * k + n % 100))
            entry[1], entry[2] = n, buf
        for sock, entry in list(state.items()):    # a client that waits too long asks again
            if time.monotonic() - entry[3] > timeout_s:
                lost += 1
                entry[1] += 1
                entry[3] = time.monotonic()
                sock.sendall(request(entry[1] & 0xFFFF, 1000 * entry[0] + entry[1] % 100))
    for sock in state:
        sock.close()
    return done / seconds, wrong, lost


# --- the contenders ---

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_listening(port: int) -> None:
    """Until something listens on port (without connecting: socat takes one connection)."""
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        if f":{port:04X} 00000000:0000 0A" in Path("/proc/net/tcp").read_text():
            return
        time.sleep(0.02)
    raise TimeoutError(f"nothing listens on port {port}")


def wait_port(port: int) -> None:
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"nothing listens on {port}")


def start_device(late: bool, tally: Path) -> tuple[int, subprocess.Popen]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, __file__, "--device", str(port), "--tally",
                             str(tally)] + (["--late"] if late else []),
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "READY"
    return port, proc


def start_mbgw(device_port: int, tmp: Path, timeout_ms: int,
               checkout: Path = CHECKOUT) -> tuple[int, subprocess.Popen]:
    master, slave = os.openpty()      # line serial: a pty nobody answers on
    tty = os.ttyname(slave)
    os.close(slave)
    port = free_port()
    config = tmp / "mbgw.toml"
    config.write_text("[[line]]\nname = \"inverter\"\n"
                      f"connect = \"modbus-tcp://127.0.0.1:{device_port}\"\n"
                      f"stout = {timeout_ms}\n"
                      "[[route]]\nunits = \"1\"\nline = \"inverter\"\n")
    proc = subprocess.Popen(
        [sys.executable, "-m", "mbgw", "slave", "--device", tty, "--bind", "127.0.0.1",
         "--mdbport", str(port), "--config", str(config), "--exception",
         "--max-connections", "40", "--max-connections-per-ip", "40"],
        cwd=checkout, env=dict(os.environ, RUNTIME_DIRECTORY=str(tmp)),
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    proc.pty_master = master      # type: ignore[attr-defined]  (kept open while it runs)
    wait_port(port)
    return port, proc


def start_proxy(device_port: int, timeout_ms: int) -> tuple[int, subprocess.Popen]:
    port = free_port()
    exe = Path(sys.executable).parent / "modbus-proxy"
    proc = subprocess.Popen([str(exe), "-b", f"tcp://127.0.0.1:{port}", "--modbus",
                             f"tcp://127.0.0.1:{device_port}", "--timeout",
                             str(timeout_ms / 1000)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_port(port)
    return port, proc


def start_relay(device_port: int) -> tuple[int, subprocess.Popen]:
    """socat copying bytes between one client and the device, both ways (TCP_NODELAY): the
    least any gateway in between costs on this host (one connection, then it exits)."""
    port = free_port()
    proc = subprocess.Popen(["socat", f"TCP-LISTEN:{port},bind=127.0.0.1,reuseaddr,nodelay",
                             f"TCP:127.0.0.1:{device_port},nodelay"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_listening(port)
    return port, proc


def stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def pct(values: list[int], q: float) -> float:
    return values[min(len(values) - 1, max(0, round(q / 100 * len(values)) - 1))] / 1000


CONTENDERS = ("direct", "socat relay", "mbgw", "modbus-proxy")
RATED = ("mbgw", "modbus-proxy")      # also rated with 8 and 32 clients


def start_contender(name: str, device_port: int, run_dir: Path, timeout_ms: int):
    if name == "mbgw":
        return start_mbgw(device_port, run_dir, timeout_ms)
    if name == "socat relay":
        return start_relay(device_port)
    return start_proxy(device_port, timeout_ms)


def run(quick: bool) -> None:
    count = 300 if quick else 2000
    seconds = 1.5 if quick else 5.0
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        procs: list[subprocess.Popen] = []
        try:
            served = {}
            for name in CONTENDERS:
                run_dir = Path(tmp) / name.replace(" ", "-")
                run_dir.mkdir()
                device_port, dev = start_device(False, run_dir / "tally")
                procs.append(dev)
                port, busy = (device_port, dev) if name == "direct" else \
                    start_contender(name, device_port, run_dir, 1000)
                if busy is not dev:
                    procs.append(busy)
                served[name] = (port, busy.pid)
            lat, cpus = in_turn(served, count)
            for name, (port, _) in served.items():
                rates = [closed_loop(port, n, seconds)[0] if name in RATED or n == 1
                         else float("nan") for n in (1, 8, 32)] if name != "socat relay" \
                    else [float("nan")] * 3
                rows[name] = (lat[name], rates)
        finally:
            for proc in procs:
                stop(proc)
        late = {}
        tally = Path(tmp) / "tally"
        for name in ("mbgw", "modbus-proxy"):
            device_port, dev = start_device(True, tally)
            try:
                port, gw = start_mbgw(device_port, Path(tmp), TIMEOUT_MS) if name == "mbgw" \
                    else start_proxy(device_port, TIMEOUT_MS)
                try:
                    late[name] = (*closed_loop(port, 8, seconds * 2, timeout_s=1.0),
                                  *map(int, tally.read_text().split()))
                finally:
                    stop(gw)
            finally:
                stop(dev)
    report(rows, late, count, seconds)
    print("CPU a request, one client (the process's threads, user + system; direct: the "
          "device's): " + ", ".join(f"{name} {us:.0f} us" for name, us in cpus.items()))
    floor = handover_floor(count)
    print(f"reference floor, two Python threads waking each other by eventfd after "
          f"{SERVICE_S * 1000:g} ms idle: one round trip (two crossings) p50 "
          f"{pct(floor, 50):.0f} us, p99 {pct(floor, 99):.0f} us")
    rtu_over_tcp(quick)


def versus(other: Path, quick: bool) -> None:
    """Direct, this checkout's mbgw and other's (another checkout, its C core built), each
    with a device of its own, answering one client in turn, a round of 100 requests each,
    so that all three see the same load: p50/p99, what each gateway adds, its CPU."""
    count = 300 if quick else 2000
    names = ("direct", "mbgw", f"mbgw {other.name}")
    procs: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory() as tmp:
        try:
            served = {}         # name: (its port, the process whose CPU it is)
            for name, checkout in zip(names, (None, CHECKOUT, other), strict=True):
                run_dir = Path(tmp) / name.replace(" ", "-")
                run_dir.mkdir()
                device_port, dev = start_device(False, run_dir / "tally")
                procs.append(dev)
                port, busy = device_port, dev
                if checkout is not None:
                    port, busy = start_mbgw(device_port, run_dir, 1000, checkout)
                    procs.append(busy)
                served[name] = (port, busy.pid)
            lat, cpu = in_turn(served, count)
        finally:
            for proc in procs:
                stop(proc)
    direct = lat["direct"]
    print(f"in turn, rounds of 100, {count} requests each:")
    for name in names:
        values = lat[name]
        added = "" if name == "direct" else \
            f"  +p50 {pct(values, 50) - pct(direct, 50):4.0f}" \
            f"  +p99 {pct(values, 99) - pct(direct, 99):5.0f}"
        print(f"  {name:22} p50 {pct(values, 50):5.0f}  p99 {pct(values, 99):5.0f}{added}"
              f"  CPU {cpu[name]:4.0f} us a request")


RTU_BAUD = 115200


def rtu_over_tcp(quick: bool) -> None:
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(CHECKOUT))
    import bench  # bench/bench.py: the simulated slave and its closed-loop clients
    seconds = 2.0 if quick else 8.0
    limit = 1e6 / (bench.wire_us(RTU_BAUD) + bench.t35_us(RTU_BAUD))
    with tempfile.TemporaryDirectory() as tmp:
        exe = bench.build_simline(Path(tmp))
        tty = Path(tmp) / "ttyDS"
        server_port = free_port()
        socat = subprocess.Popen(["socat", f"pty,raw,echo=0,link={tty}",
                                  f"tcp-listen:{server_port},reuseaddr"],
                                 stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while not tty.exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        slave = bench.Slave(exe, str(tty), RTU_BAUD)
        master, pty = os.openpty()        # line serial: a pty nobody answers on
        gw = None
        try:
            port = free_port()
            config = Path(tmp) / "mbgw.toml"
            config.write_text(f"[[line]]\nname = \"dtu\"\n"
                              f"connect = \"rtu-over-tcp://127.0.0.1:{server_port}\"\n"
                              "stout = 1000\n[[route]]\nunits = \"1\"\nline = \"dtu\"\n")
            gw = subprocess.Popen(
                [sys.executable, "-m", "mbgw", "slave", "--device", os.ttyname(pty), "--bind",
                 "127.0.0.1", "--mdbport", str(port), "--config", str(config),
                 "--max-connections", "40", "--max-connections-per-ip", "40"],
                cwd=CHECKOUT, env=dict(os.environ, RUNTIME_DIRECTORY=tmp),
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            wait_port(port)
            run = bench.run_clients(port, 8, slave, 0.5, seconds)
        finally:
            if gw is not None:
                stop(gw)
            slave.stop()
            stop(socat)
            os.close(master)
            os.close(pty)
    rate = run.count / run.seconds
    wire_only = 1e6 / bench.wire_us(RTU_BAUD)
    print(f"RTU over TCP (socat to a pty at {RTU_BAUD}, simline slave), 8 clients for "
          f"{seconds:g} s: {rate:.0f} transactions/s, {run.errors} errors; the line's limit "
          f"{limit:.0f}/s (wire time + t3.5): {rate / limit:.3f} of it; "
          f"{rate / wire_only:.3f} of the wire time alone ({wire_only:.0f}/s)")


def report(rows: dict, late: dict, count: int, seconds: float) -> None:
    direct_p50 = pct(rows["direct"][0], 50)
    direct_p99 = pct(rows["direct"][0], 99)
    print(f"device: Modbus TCP, one client, {SERVICE_S * 1000:g} ms a request; {count} "
          f"requests one at a time, {seconds:g} s a closed-loop run")
    print(f"{'':14}{'p50 us':>9}{'p99 us':>9}{'+p50 us':>9}{'+p99 us':>9}"
          f"{'1 client/s':>12}{'8 clients/s':>12}{'32 clients/s':>13}")
    for name, (lat, rates) in rows.items():
        p50, p99 = pct(lat, 50), pct(lat, 99)
        added = "" if name == "direct" else f"{p50 - direct_p50:>9.0f}{p99 - direct_p99:>9.0f}"
        blank = "(1 client)" if name == "direct" else "-"
        print(f"{name:14}{p50:>9.0f}{p99:>9.0f}{added or '':>18}"
              + "".join(f"{r:>12.0f}" if r == r else f"{blank:>12}" for r in rates))
    print(f"late replies: every {LATE_EVERY}th answered {LATE_S * 1000:g} ms late, timeout "
          f"{TIMEOUT_MS} ms, 8 clients for {seconds * 2:g} s")
    for name, (rate, wrong, lost, accepted, resets) in late.items():
        print(f"{name:14}{rate:>6.0f} replies/s{wrong:>6} wrong deliveries{lost:>6} lost"
              f"{accepted:>6} device connections{resets:>6} reset")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--versus", type=Path, metavar="CHECKOUT",
                        help="only: this mbgw and CHECKOUT's in turn, with direct")
    parser.add_argument("--device", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--late", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--tally", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.device:
        device(args.device, args.late, args.tally)
        return
    if args.versus:
        versus(args.versus.resolve(), args.quick)
        return
    run(args.quick)


if __name__ == "__main__":
    main()
