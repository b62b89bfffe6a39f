"""What the master-mode diagnostics and reload tests share: pymodbus Modbus TCP servers on
loopback addresses (peers/pymodbus_tcp_servers.py), `mbgw master` on a socat pty, the
master's end of the line as a raw fd, and the operator's commands over the control socket.

Readiness is always an event: a server's READY, the gateway's READY=1, a frame back on the
line, a log line, or a condition on the daemon's own status (polled over the control socket
where the daemon does something on its own after the last event a test can see)."""
import json
import os
import subprocess
import sys
import time

import pytest

from tests.harness import Gateway, Peer, free_port
from tests.integration.test_master import (BAUD, REPLY_S, holding_reply, identity,
                                           read_holding, recv, rtu)
from mbgw import control

__all__ = ["BAUD", "REPLY_S", "holding_reply", "identity", "read_holding", "recv", "rtu",
           "servers_at", "start_master", "line", "ask", "unanswered", "mbgw", "status", "wait_for",
           "wait_for_log", "stop_counters"]

CONDITION_TIMEOUT_S = 5.0


@pytest.fixture
def servers_at():
    """servers_at(*hosts, silent=(), port=None) -> (port, Peer): pymodbus servers on these
    loopback addresses and on the silent ones (which never answer), all on one port;
    stopped after the test."""
    started = []

    def start(*hosts: str, silent=(), port: int | None = None):
        port = port or free_port()
        args = [str(port), *hosts, *silent]
        if silent:
            args += ["--silent", *silent]
        peer = Peer("pymodbus_tcp_servers.py", *args)
        started.append(peer)
        return port, peer

    yield start
    for peer in started:
        peer.stop()


@pytest.fixture
def start_master(tmp_path, pty_pair):
    """start_master(*options) -> a ready `mbgw master` on the pty at BAUD; stopped after."""
    started = []

    def start(*options: str) -> Gateway:
        gw = Gateway(tmp_path, pty_pair.gateway, "--baudrate", BAUD, *options, mode="master",
                     listen=False)
        started.append(gw)
        return gw

    yield start
    for gw in started:
        gw.stop()


@pytest.fixture
def line(pty_pair):
    """The master's end of the line as a raw fd."""
    fd = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)
    yield fd
    os.close(fd)


def ask(fd: int, *frames: bytes, expected: bytes) -> None:
    """Write the requests (ADUs without CRC) on the line; the first frame back must be
    `expected` (an ADU without CRC)."""
    os.write(fd, b"".join(map(rtu, frames)))
    want = rtu(expected)
    got = recv(fd, len(want))
    assert got == want, f"wrote {[f.hex(' ') for f in frames]}: got {got.hex(' ')!r}, " \
                        f"expected {want.hex(' ')!r}"


def unanswered(fd: int, *frames: bytes, then: bytes, expected: bytes) -> None:
    """The requests get no answer: the request `then`, written right behind them, gets its
    answer `expected` first."""
    ask(fd, *frames, then, expected=expected)


def mbgw(*args: str, timeout: float = 15) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mbgw", *args], capture_output=True,
                          text=True, timeout=timeout)


def status(gw) -> dict:
    """`mbgw status --json`, as an operator runs it."""
    result = mbgw("status", "--json", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def wait_for(gw, condition, what: str) -> dict:
    """The daemon's status once condition(status) holds."""
    deadline = time.monotonic() + CONDITION_TIMEOUT_S
    while True:
        s = control.call(gw.control, {"command": "status"})
        if condition(s):
            return s
        assert time.monotonic() < deadline, f"never {what}: {s}"
        time.sleep(0.02)


def wait_for_log(gw, text: str, count: int = 1) -> str:
    deadline = time.monotonic() + CONDITION_TIMEOUT_S
    while (log := gw.log()).count(text) < count:
        assert time.monotonic() < deadline, f"no {text!r} in the log:\n{log}"
        time.sleep(0.02)
    return log


def stop_counters(gw) -> dict[str, int]:
    """Stop the gateway; the counters it logs at stop."""
    assert gw.stop() == 0, gw.log_path.read_text()
    text = gw.log_path.read_text()
    lines = [l for l in text.splitlines() if "stopped; counters:" in l]
    assert len(lines) == 1, text
    return {k: int(v) for k, v in (w.split("=") for w in lines[0].split("counters:")[1].split())}
