#!/usr/bin/env python3
"""Reads that share one transaction (issue 27).  Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py --cache [--quick]      (or bench/cache.py [--quick])

Two measures, each beside its reference from the same run:

  * line transactions per client request: 5 pymodbus clients read the same 10 registers at
    20 Hz from a pymodbus RTU slave (tests/peers/pymodbus_slave.py, recording what the line
    carried) behind `mbgw slave` at 19200, first without `cache`, then with
    `cache = { ttl = 500 }`: transactions on the line / requests answered.
  * cache hits over loopback: `mbgw slave` with `cache = { ttl = 3600000 }`, the range read
    once, then FC03 of 10 registers from address 0 by 1 and 32 closed-loop clients
    (bench/tableload.c, as bench/table.py): every request a hit.  Beside it, in the same
    rounds, the exchange table's server on the same load (`mbgw slave --table --no-direct`,
    table.py's "mbgw slave"): the rate the issue aims at.  p50/p99 latency (request sent ->
    whole reply read, at the client) and requests/s.

See README.md, "Reads that share one transaction".
"""
import os
import sys
import tempfile
import threading
import time
from array import array
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

import table  # noqa: E402  (bench/table.py, beside this script)
from pymodbus.client import ModbusTcpClient  # noqa: E402

import bench  # noqa: E402  (bench/bench.py, beside this script)
from tests.harness import Gateway, Peer, PtyPair  # noqa: E402

UNIT = table.UNIT              # tableload's unit
POLLERS = 5
POLL_HZ = 20
HIT_CLIENTS = (1, 32)
HIT_REGISTERS = 10


class CachedGateway:
    """mbgw slave on a socat pty pair with a pymodbus slave at UNIT, `cache` in its file."""

    def __init__(self, name: str, tmp: Path, cache: str | None) -> None:
        self.name = name
        directory = Path(tempfile.mkdtemp(dir=tmp))
        self.pair = PtyPair(directory)
        self.record = directory / "record.txt"
        self.peer = Peer("pymodbus_slave.py", self.pair.device, str(UNIT), "--silent-unknown",
                         "--record", str(self.record))
        config = directory / "mbgw.toml"
        config.write_text(f"[serial]\ncache = {cache}\n" if cache else "")
        try:
            self.gateway = Gateway(directory, self.pair.gateway, "--config", str(config),
                                   "--baudrate", "19200", "--stout", "300",
                                   "--log-level", "warning", "--max-connections",
                                   str(max(HIT_CLIENTS) + 8))
        except BaseException:
            self.peer.stop()
            self.pair.stop()
            raise
        self.port = self.gateway.port

    @property
    def pid(self) -> int:
        return self.gateway.proc.pid

    def transactions(self) -> int:
        return sum(" rx " in row for row in self.record.read_text().splitlines())

    def stop(self) -> None:
        self.gateway.stop()
        self.peer.stop()
        self.pair.stop()


def poll(port: int, seconds: float) -> tuple[int, int]:
    """POLLERS clients at POLL_HZ for seconds: (requests answered, failed)."""
    answered, failed = [], []

    def client() -> None:
        c = ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
        c.connect()
        count, errors, next_at = 0, 0, time.monotonic()
        stop_at = next_at + seconds
        while next_at < stop_at:
            try:
                ok = not c.read_holding_registers(0, count=10, device_id=UNIT).isError()
            except Exception:       # pymodbus raises on a timeout
                ok = False
            count += ok
            errors += not ok
            next_at += 1 / POLL_HZ
            time.sleep(max(0.0, next_at - time.monotonic()))
        c.close()
        answered.append(count)
        failed.append(errors)

    threads = [threading.Thread(target=client) for _ in range(POLLERS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(answered), sum(failed)


def transactions_per_request(tmp: Path, seconds: float) -> None:
    print(f"\n  Line transactions per client request: {POLLERS} clients, {POLL_HZ} Hz each, "
          f"10 registers, {seconds:g} s, 19200 baud")
    print(f"  {'gateway':28} {'answered':>8} {'failed':>6} {'on line':>8} {'per request':>11}")
    for name, cache in (("without cache", None), ("cache = { ttl = 500 }", "{ ttl = 500 }")):
        gw = CachedGateway(name, tmp, cache)
        try:
            before = gw.transactions()
            answered, failed = poll(gw.port, seconds)
            on_line = gw.transactions() - before
        finally:
            gw.stop()
        print(f"  {name:28} {answered:8d} {failed:6d} {on_line:8d} "
              f"{on_line / max(answered, 1):11.3f}")


def hits(tmp: Path, rounds: int, warmup: float, seconds: float) -> None:
    load, _ = table.build(tmp)
    cached = CachedGateway("mbgw cache hit", tmp, "{ ttl = 3600000 }")
    servers: list = [cached]
    try:
        c = ModbusTcpClient("127.0.0.1", port=cached.port, timeout=3, retries=0)
        c.connect()
        assert not c.read_holding_registers(0, count=HIT_REGISTERS, device_id=UNIT).isError()
        c.close()
        servers.append(table.MbgwServer("mbgw table", tmp, "slave"))
        runs = []
        latency_file = tmp / "latencies"
        for clients in HIT_CLIENTS:
            case = [table.TableRun(s.name, HIT_REGISTERS, clients) for s in servers]
            for _ in range(rounds):
                for server, run in zip(servers, case, strict=True):
                    table.run_load(load, server, run, warmup, seconds, latency_file)
            for run in case:
                run.latencies = array("Q", sorted(run.latencies))
            runs += case
        on_line = cached.transactions()
    finally:
        for server in servers:
            server.stop()
    print(f"\n  Cache hits over loopback, FC03 of {HIT_REGISTERS} registers, closed loop "
          f"({rounds} rounds of {seconds:g} s, the two in turn)")
    print(f"  {'server':16} {'clients':>7} {'req/s':>8} {'p50 us':>7} {'p99 us':>7} "
          f"{'us/req':>7} {'errors':>6}")
    for r in runs:
        print(f"  {r.server:16} {r.clients:7d} {r.rate:8.0f} {r.latency_us(50):7.0f} "
              f"{r.latency_us(99):7.0f} {r.server_us_per_request:7.1f} {r.errors:6d}")
    print(f"  (the line carried {on_line} transaction(s) meanwhile: the read that filled the "
          "cache; us/req: the gateway's CPU, every thread)")


def run(quick: bool) -> None:
    rounds, warmup, seconds = (2, 0.1, 0.5) if quick else (5, 0.2, 1.0)
    poll_s = 3.0 if quick else 10.0
    began = time.monotonic()
    print("mbgw bench, the read cache (issue 27)")
    print(f"  host: {os.cpu_count()} CPUs; load average before: {table.loadavg()}")
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-cache-") as tmp_name:
        tmp = Path(tmp_name)
        transactions_per_request(tmp, poll_s)
        hits(tmp, rounds, warmup, seconds)
    print(f"\n({time.monotonic() - began:.0f} s; load average after: {table.loadavg()})")


def main() -> None:
    bench.quick_main(__doc__, run, "short runs (about 20 s)")


if __name__ == "__main__":
    main()
