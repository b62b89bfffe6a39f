#!/usr/bin/env python3
"""Modbus/TCP Security's row (issue 17): what TLS costs, on the same gateway and the same
slave as plain Modbus TCP.  Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py --tls [--quick]      (or bench/tls.py [--quick])

One `mbgw slave --table --table-units 247 --baudrate 115200` with TLS on (certificates made by
openssl as in tests/pki.py: EC P-256, TLS 1.3), pymodbus's RTU slave 17 on a socat pty.

  * handshakes/s: one client connecting, shaking hands (its certificate checked, its role
    read) and closing, one after the other, for the window; and the median handshake (connect
    to handshake done, at the client);
  * a poll per connection, full and resumed handshakes (issue 23): a client that connects,
    reads 10 registers of the table and closes, one after the other, in TLS 1.2 and 1.3, with
    a full handshake each time and with the session of the connection before (tickets):
    connections per second and the median connection (connect to reply read);
  * latency added per request: one client in a closed loop of FC03 reads of 10 registers,
    plain and TLS in turns (rounds of each, one after the other, so a drift of the host weighs
    on both alike), for unit 247 (answered from the table: no serial line, so the difference
    is TLS alone) and unit 17 (through the line).  p50/p99 from request sent to whole reply
    read at the client, whose own TLS work (Python's ssl) is in the figure too.
"""
import os
import socket
import ssl
import struct
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

import bench  # noqa: E402  (bench/bench.py, beside this script)
from tests.harness import Gateway, free_port  # noqa: E402
from tests.pki import Authority  # noqa: E402

os.environ.setdefault("MBGW_CONFIG", os.devnull)   # not an installed /etc/mbgw/mbgw.toml
TABLE_UNIT = 247
LINE_UNIT = 17
BAUD = "115200"


def request(tid: int, unit: int) -> bytes:
    return struct.pack(">HHHBBHH", tid & 0xFFFF, 0, 6, unit, 3, 0, 10)


def read_reply(sock) -> None:
    need, got = 6, b""
    while len(got) < need:
        chunk = sock.recv(need - len(got))
        if not chunk:
            raise EOFError("the gateway closed the connection")
        got += chunk
        if len(got) == 6:
            need = 6 + struct.unpack(">H", got[4:6])[0]


def closed_loop(sock, unit: int, seconds: float) -> list[int]:
    """Latencies (ns) of back-to-back requests for seconds."""
    latencies = []
    end = time.monotonic() + seconds
    tid = 0
    while time.monotonic() < end:
        tid += 1
        start = time.monotonic_ns()
        sock.sendall(request(tid, unit))
        read_reply(sock)
        latencies.append(time.monotonic_ns() - start)
    return latencies


def pct(values: list[int], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(len(ordered) * q / 100))] / 1000


def handshakes(port: int, context: ssl.SSLContext, seconds: float) -> tuple[float, float]:
    """(handshakes per second, median handshake in us)."""
    times = []
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        began = time.monotonic_ns()
        with socket.create_connection(("127.0.0.1", port)) as raw:
            with context.wrap_socket(raw):
                times.append(time.monotonic_ns() - began)
    elapsed = time.monotonic() - start
    return len(times) / elapsed, pct(times, 50)


def polls(port: int, context: ssl.SSLContext, seconds: float,
          resume: bool) -> tuple[float, float, int]:
    """(connections per second, median connection in us, how many resumed): each connects,
    reads 10 registers of the table and closes; resume: with the session of the one before."""
    times, resumed, session = [], 0, None
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        began = time.monotonic_ns()
        with socket.create_connection(("127.0.0.1", port)) as raw:
            raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with context.wrap_socket(raw, session=session if resume else None) as sock:
                sock.sendall(request(len(times), TABLE_UNIT))
                read_reply(sock)
                times.append(time.monotonic_ns() - began)
                resumed += sock.session_reused
                session = sock.session
    elapsed = time.monotonic() - start
    return len(times) / elapsed, pct(times, 50), resumed


def run(quick: bool) -> None:
    rounds, window = (3, 0.5) if quick else (6, 1.5)
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-tls-") as name:
        tmp = Path(name)
        ca = Authority(tmp)
        cert, key = ca.issue("server", server=True)
        client_cert = ca.issue("bench", role="operator")
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
        context.check_hostname = False
        context.load_verify_locations(str(ca.cert))
        context.load_cert_chain(str(client_cert[0]), str(client_cert[1]))
        with bench.pymodbus_line(tmp, LINE_UNIT) as pair:
            tls_port = free_port()
            gw = Gateway(tmp, pair.gateway, "--baudrate", BAUD, "--table", "--table-units",
                         str(TABLE_UNIT), "--max-connections", "10", "--tls-port", str(tls_port),
                         "--tls-cert", str(cert), "--tls-key", str(key), "--tls-ca", str(ca.cert))
            try:
                print(f"load average {os.getloadavg()[0]:.2f}; TLS 1.3, EC P-256; "
                      f"{rounds} rounds of {window} s per row")
                rate, median = handshakes(tls_port, context, window * rounds / 2)
                print(f"handshakes: {rate:.0f}/s, one at a time; median {median:.0f} us")
                print(f"{'a poll per connection':<24}{'full/s':>8}{'p50 us':>8}"
                      f"{'resumed/s':>11}{'p50 us':>8}")
                for version in (ssl.TLSVersion.TLSv1_2, ssl.TLSVersion.TLSv1_3):
                    context.maximum_version = version
                    full = polls(tls_port, context, window * rounds / 4, resume=False)
                    again = polls(tls_port, context, window * rounds / 4, resume=True)
                    assert again[2] >= again[0] * window * rounds / 4 - 2, "sessions not resumed"
                    print(f"{version.name:<24}{full[0]:>8.0f}{full[1]:>8.0f}{again[0]:>11.0f}"
                          f"{again[1]:>8.0f}")
                context.maximum_version = ssl.TLSVersion.TLSv1_3
                plain = socket.create_connection(("127.0.0.1", gw.port))
                plain.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                secure = context.wrap_socket(socket.create_connection(("127.0.0.1", tls_port)))
                secure.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                print(f"{'unit':<14}{'plain p50':>10}{'p99':>8}{'TLS p50':>10}{'p99':>8}"
                      f"{'added p50':>11}   (us)")
                for unit, what in ((TABLE_UNIT, "table"), (LINE_UNIT, "line")):
                    runs: dict[str, list[int]] = {"plain": [], "tls": []}
                    for _ in range(rounds):
                        runs["plain"] += closed_loop(plain, unit, window)
                        runs["tls"] += closed_loop(secure, unit, window)
                    p, t = runs["plain"], runs["tls"]
                    print(f"{unit:>3} ({what}) {pct(p, 50):>10.0f}{pct(p, 99):>8.0f}"
                          f"{pct(t, 50):>10.0f}{pct(t, 99):>8.0f}{pct(t, 50) - pct(p, 50):>11.0f}")
                plain.close()
                secure.close()
                print(f"load average after {os.getloadavg()[0]:.2f}")
            finally:
                gw.stop()


def main() -> None:
    bench.quick_main(__doc__, run, "short runs")


if __name__ == "__main__":
    main()
