#!/usr/bin/env python3
"""The firewall's cost per request (issue 17): prints figures, never pass/fail.

    .venv/bin/python bench/firewall.py [--quick]

What slave mode's TcpServer.request and the table server do per request, timed in a loop
(time.perf_counter_ns over N requests, best of 5 runs): without rules (the client's guard is
None: one attribute test) and with 20 rules, the client selected by the 20th (units, a
function list and two register ranges, so every check runs: unit, function, the address range
from the PDU).  Beside it, the connect-time cost of picking and compiling the client's rule
among the 20 (Firewall.guard).  The requests: FC 3, FC 16 and FC 23, allowed (a refused one
costs its count and log besides, once).
"""
import argparse
import struct
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mbgw.config.firewall import from_file
from mbgw.firewall.guard import Firewall

REQUESTS = [struct.pack(">BHH", 3, 10, 10),
            struct.pack(">BHHB", 16, 100, 2, 4) + bytes(4),
            struct.pack(">BHHHHB", 23, 10, 2, 120, 2, 4) + bytes(4)]


def twenty_rules() -> Firewall:
    rules = [{"client": f"10.{i}.0.0/16", "units": "1-5", "read-only": True}
             for i in range(19)]
    rules.append({"client": "127.0.0.0/8", "units": "1-10,20", "functions": [3, 4, 16, 23],
                  "registers": "0-99,100-199"})
    cfg, problems = from_file({"firewall": {"default": "deny"}, "rule": rules})
    assert not problems, problems
    return Firewall(cfg)


def per_request_ns(guard, n: int) -> float:
    """ns per request of `guard is not None and not guard.allows(unit, pdu)`."""
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter_ns()
        for i in range(n):
            request = REQUESTS[i % 3]
            if guard is not None and not guard.allows(1, request):
                raise AssertionError("refused")
        best = min(best, (time.perf_counter_ns() - start) / n)
    return best


def loop_ns(n: int) -> float:
    """The loop alone (indexing the request), subtracted from both."""
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter_ns()
        for i in range(n):
            REQUESTS[i % 3]
        best = min(best, (time.perf_counter_ns() - start) / n)
    return best


def connect_us(firewall: Firewall, n: int) -> float:
    start = time.perf_counter_ns()
    for _ in range(n):
        firewall.guard("127.0.0.1", None, "plain")
    return (time.perf_counter_ns() - start) / n / 1000


def main(quick: bool = False) -> None:
    n = 100_000 if quick else 1_000_000
    firewall = twenty_rules()
    guard = firewall.guard("127.0.0.1", None, "plain")
    assert guard is not None and guard.rule is not None and guard.rule.index == 20
    base = loop_ns(n)
    print(f"firewall check per request ({n} requests, best of 5, loop cost {base:.0f} ns "
          "taken off)")
    print(f"  no rules (guard None)    {per_request_ns(None, n) - base:8.0f} ns")
    print(f"  20 rules (the 20th)      {per_request_ns(guard, n) - base:8.0f} ns")
    compile_us = connect_us(firewall, 2000)
    print(f"  at connect: the client's rule among 20, compiled: {compile_us:.1f} us")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    main(ap.parse_args().quick)
