#!/usr/bin/env python3
"""Northbound MQTT's row (issue 28): what publishing 10,000 metric changes a second costs the
daemon, and whether it moves the line.  Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py --mqtt [--quick]      (or bench/mqtt.py [--quick])

Two gateways in turns, the same but for `[mqtt]`: 100 scenarios (FC 3, 10 registers from
unit 1 of bench.py's simline slave at 115200, each read once at start: cycle 65535 ms) make
1,000 metrics of one Sparkplug device; a Modbus TCP writer puts new values in all 1,000
registers of the table 10 times a second (FC 16 to table unit 247, 100 registers a request),
10,000 changes a second; and one closed-loop Modbus TCP client reads through the line
meanwhile (its latency is the line's). Debian's Mosquitto on 127.0.0.1 takes the gateway's
messages, and a subscriber counts the metrics they carry.

Columns: the daemon's CPU time (every thread, /proc/PID/stat) in % of one core over the
window, with MQTT off and on, and the difference: what MQTT costs beyond the line's and the
writer's own; the line client's rate and latency p50/p99; the metrics received per second.
See README.md, "Northbound MQTT".
"""
import argparse
import os
import shutil
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import bench  # noqa: E402  (bench/bench.py, beside this script)
from mbgw.northbound.sparkplug_b_pb2 import Payload  # noqa: E402
from tests.peers.broker import Broker, Subscriber  # noqa: E402

BAUD = 115200
SCENARIOS = 100
REGISTERS = 10                     # each scenario's: simline answers FC 3 of 10 registers
TABLE_UNIT = 247
ROUNDS_PER_S = 10                  # 1,000 registers each: 10,000 changes a second
PER_REQUEST = 100
TICKS = os.sysconf("SC_CLK_TCK")


def config(path: Path, broker: str | None) -> None:
    lines = ["[serial]", 'mode = "slave"', f"baudrate = {BAUD}", "stout = 1000"]
    if broker is not None:
        lines += ["[mqtt]", f'broker = "{broker}"', 'group = "bench"', 'node = "gw"']
    for n in range(SCENARIOS):
        lines += ["[[scenario]]", f'name = "s{n:03d}"', "slave = 1", "function = 3",
                  "address = 0", f"quantity = {REGISTERS}", f"table = {REGISTERS * n}",
                  "cycle = 65535"]
    path.write_text("\n".join(lines) + "\n")


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS      # utime, stime


class Writer(threading.Thread):
    """FC 16 to the table unit: every register of the scenarios' range, ROUNDS_PER_S times a
    second, each round new values."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        import socket
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.stop_at = 0.0
        self.rounds = 0

    def run(self) -> None:
        tid = 0
        next_round = time.monotonic()
        while time.monotonic() < self.stop_at:
            for first in range(0, SCENARIOS * REGISTERS, PER_REQUEST):
                tid = (tid + 1) & 0xFFFF
                values = [(self.rounds + first + i) & 0xFFFF for i in range(PER_REQUEST)]
                pdu = struct.pack(f">BHHB{PER_REQUEST}H", 16, first, PER_REQUEST,
                                  2 * PER_REQUEST, *values)
                self.sock.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, TABLE_UNIT) + pdu)
                self.sock.recv(64)
            self.rounds += 1
            next_round += 1 / ROUNDS_PER_S
            time.sleep(max(0.0, next_round - time.monotonic()))


def measure(exe: str, tmp: Path, broker: Broker | None, counter: "MetricCounter | None",
            warmup: float, seconds: float) -> dict:
    side = bench.Side(exe, tmp, False, BAUD)
    path = tmp / f"mqtt-{'on' if broker else 'off'}.toml"
    config(path, broker.url if broker else None)
    try:
        gw = bench.Gateway(tmp, side.device, "--config", str(path), "--table",
                           "--log-level", "warning")
        try:
            time.sleep(warmup + 1.0)           # the 100 scenarios' first reads
            writer = Writer(gw.port)
            writer.stop_at = time.monotonic() + warmup + seconds + 1.0
            writer.start()
            time.sleep(warmup)
            before, metrics_before = cpu_s(gw.proc.pid), counter.count if counter else 0
            rounds_before = writer.rounds
            began = time.monotonic()
            client = bench.run_clients(gw.port, 1, side.slave, 0.0, seconds)
            spent = time.monotonic() - began
            cpu = cpu_s(gw.proc.pid) - before
            received = (counter.count - metrics_before) if counter else 0
            written = (writer.rounds - rounds_before) * SCENARIOS * REGISTERS
            writer.join()
        finally:
            gw.stop()
    finally:
        side.stop()
    return {"cpu_pct": 100 * cpu / spent, "rate": client.rate, "p50": client.lat_ms(50),
            "p99": client.lat_ms(99), "metrics_per_s": received / spent,
            "changes_per_s": written / spent}


class MetricCounter:
    """Metrics carried by the DDATA the broker delivers."""

    def __init__(self, broker: Broker) -> None:
        self.count = 0
        self.sub = Subscriber(broker.port, "spBv1.0/bench/DDATA/#", client_id="bench")
        self.sub.client.on_message = self._message

    def _message(self, client, userdata, message) -> None:
        payload = Payload()
        payload.ParseFromString(message.payload)
        self.count += len(payload.metrics)


def run(quick: bool) -> None:
    seconds, warmup, rounds = (3.0, 0.5, 1) if quick else (8.0, 1.0, 3)
    print("mbgw bench, northbound MQTT: 1,000 metrics, 10,000 changes/s from the table, "
          f"a line client at {BAUD} baud")
    if shutil.which("mosquitto") is None and not Path("/usr/sbin/mosquitto").exists():
        print("  mosquitto is not installed (scripts/setup.sh installs it)")
        return
    print(f"  load average before: {bench._loadavg()}")
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-") as tmp_name:
        tmp = Path(tmp_name)
        exe = bench.build_simline(tmp)
        broker = Broker(tmp)
        counter = MetricCounter(broker)
        runs: dict[str, list[dict]] = {"off": [], "on": []}
        try:
            for _ in range(rounds):       # in turns: a drift of the host weighs on both
                runs["off"].append(measure(exe, tmp, None, None, warmup, seconds))
                runs["on"].append(measure(exe, tmp, broker, counter, warmup, seconds))
        finally:
            counter.sub.close()
            broker.stop()
    show = {k: {f: sorted(r[f] for r in v)[len(v) // 2] for f in v[0]} for k, v in runs.items()}
    for name, r in show.items():
        print(f"    MQTT {name:3}  daemon CPU {r['cpu_pct']:5.1f} % of a core; line client "
              f"{r['rate']:7.1f} tx/s, p50 {r['p50']:.2f} ms, p99 {r['p99']:.2f} ms"
              f"; {r['changes_per_s']:.0f} changes/s written"
              + (f", {r['metrics_per_s']:.0f} metrics/s received" if name == "on" else ""))
    print(f"    MQTT's cost: {show['on']['cpu_pct'] - show['off']['cpu_pct']:+.1f} % of a core; "
          f"line p99 {show['on']['p99'] - show['off']['p99']:+.2f} ms "
          f"(medians of {rounds} round{'s' if rounds > 1 else ''})")
    print(f"  load average after: {bench._loadavg()}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    run(ap.parse_args().quick)
