#!/usr/bin/env python3
"""The web console's row (issue 18): what a browser on the Traffic page costs the data path.
Prints figures, never pass/fail.

    .venv/bin/python bench/bench.py --web [--quick]      (or bench/web.py [--quick])

One `mbgw slave --baudrate 115200 --table --table-units 247` with the console on
(127.0.0.1, an admin password), pymodbus's RTU slave 17 on a socat pty.  One Modbus TCP
client in a closed loop of FC03 reads of 10 registers, in rounds with and without "a
browser": a logged-in session reading the live trace (/api/trace, server-sent events: every
transaction is two events sent to it) and polling /api/status once a second, as the Traffic
page does.  The rounds alternate, so a drift of the host weighs on both alike.  p50/p99 from
request sent to whole reply read, and requests/s, for unit 17 (through the line) and unit 247
(the table: no line, so the asyncio thread's share shows most there).
"""
import argparse
import http.cookiejar
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

from tls import closed_loop, pct  # noqa: E402

import bench  # noqa: E402  (bench/bench.py, beside this script)
from tests.harness import Gateway, free_port  # noqa: E402

os.environ.setdefault("MBGW_CONFIG", os.devnull)   # not an installed /etc/mbgw/mbgw.toml
LINE_UNIT = 17
TABLE_UNIT = 247
BAUD = "115200"
PASSWORD = "bench-password"


class Browser:
    """A logged-in session on the Traffic page, in a process of its own (as a browser is: its
    reading must not share the bench client's GIL): the SSE trace read, /api/status each
    second."""

    def __init__(self, base: str) -> None:
        self.base = base
        self.events = 0

    def watch(self, seconds: float) -> subprocess.Popen:
        """Subscribed when this returns; reads for `seconds`, then prints its event count."""
        proc = subprocess.Popen([sys.executable, __file__, "--browser", self.base,
                                 str(seconds)], stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None and proc.stdout.readline() == "READY\n"
        return proc

    def done(self, proc: subprocess.Popen) -> None:
        out, _ = proc.communicate(timeout=30)
        self.events += int(out.split()[-1])


def browse(base: str, seconds: float) -> None:
    """The browser process: log in, subscribe, say READY, read and poll for `seconds`."""
    opener = urllib.request.build_opener(
        urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
    login = urllib.request.Request(base + "/api/login", method="POST", data=json.dumps(
        {"user": "admin", "password": PASSWORD}).encode(),
        headers={"Content-Type": "application/json"})
    opener.open(login, timeout=10).read()
    stream = opener.open(base + "/api/trace", timeout=10)
    assert stream.readline() == b": trace\n"
    print("READY", flush=True)
    end = time.monotonic() + seconds
    poll, events = time.monotonic(), 0
    while time.monotonic() < end:
        if stream.readline().startswith(b"data: "):
            events += 1
        if time.monotonic() >= poll:
            opener.open(base + "/api/status", timeout=10).read()
            poll += 1.0
    stream.close()
    print(events, flush=True)


def gateway(tmp: Path, device: str, web_port: int) -> Gateway:
    path = tmp / "mbgw.toml"
    done = subprocess.run([sys.executable, "-m", "mbgw", "config", "password", "admin",
                           "--stdin", "--config", str(path)], input=PASSWORD + "\n",
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    path.write_text(path.read_text().replace("[web]\n",
                                             f'[web]\nlisten = "127.0.0.1:{web_port}"\n', 1))
    return Gateway(tmp, device, "--config", str(path), "--baudrate", BAUD, "--table",
                   "--table-units", str(TABLE_UNIT))


def run(quick: bool) -> None:
    rounds, window = (3, 0.5) if quick else (6, 1.5)
    with tempfile.TemporaryDirectory(prefix="mbgw-bench-web-") as name:
        tmp = Path(name)
        with bench.pymodbus_line(tmp, LINE_UNIT) as pair:
            web_port = free_port()
            gw = gateway(tmp, pair.gateway, web_port)
            try:
                browser = Browser(f"http://127.0.0.1:{web_port}")
                print(f"load average {os.getloadavg()[0]:.2f}; {rounds} rounds of {window} s per "
                      f"row and case, alternating")
                client = socket.create_connection(("127.0.0.1", gw.port))
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                print(f"{'unit':<14}{'no browser p50':>15}{'p99':>8}{'req/s':>8}"
                      f"{'Traffic page p50':>18}{'p99':>8}{'req/s':>8}   (us)")
                for unit, what in ((LINE_UNIT, "line"), (TABLE_UNIT, "table")):
                    runs: dict[str, list[int]] = {"off": [], "on": []}
                    for _ in range(rounds):
                        runs["off"] += closed_loop(client, unit, window)
                        reader = browser.watch(window)
                        runs["on"] += closed_loop(client, unit, window)
                        browser.done(reader)
                    off, on = runs["off"], runs["on"]
                    rate = rounds * window
                    print(f"{unit:>3} ({what:<5}) {pct(off, 50):>14.0f}{pct(off, 99):>8.0f}"
                          f"{len(off) / rate:>8.0f}{pct(on, 50):>18.0f}{pct(on, 99):>8.0f}"
                          f"{len(on) / rate:>8.0f}")
                client.close()
                print(f"trace events the browser read: {browser.events}; "
                      f"load average after {os.getloadavg()[0]:.2f}")
            finally:
                gw.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs")
    ap.add_argument("--browser", nargs=2, metavar=("URL", "SECONDS"),
                    help="be the browser process (what run() starts)")
    args = ap.parse_args()
    if args.browser:
        browse(args.browser[0], float(args.browser[1]))
    else:
        run(args.quick)


if __name__ == "__main__":
    main()
