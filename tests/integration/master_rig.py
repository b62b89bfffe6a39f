"""What the master-mode diagnostics and reload tests share: pymodbus Modbus TCP servers on
loopback addresses (peers/pymodbus_tcp_servers.py), `mbgw master` on a socat pty, the
master's end of the line as a raw fd, and the operator's commands over the control socket.

Readiness is always an event: a server's READY, the gateway's READY=1, a frame back on the
line, a log line, or a condition on the daemon's own status (polled over the control socket
where the daemon does something on its own after the last event a test can see)."""
import os

import pytest

from tests.harness import Gateway, Peer, free_port, stop_counters
from tests.integration.test_master import (BAUD, REPLY_S, holding_reply, identity,
                                           read_holding, recv, rtu)
from tests.ops import mbgw, status, wait_for, wait_for_log

__all__ = ["BAUD", "REPLY_S", "holding_reply", "identity", "read_holding", "recv", "rtu",
           "servers_at", "start_master", "line", "ask", "unanswered", "mbgw", "status", "wait_for",
           "wait_for_log", "stop_counters"]


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
def start_master(pty_pair, start_gateway):
    """start_master(*options) -> a ready `mbgw master` on the pty at BAUD; stopped after."""
    def start(*options: str) -> Gateway:
        return start_gateway(pty_pair.gateway, "--baudrate", BAUD, *options, mode="master",
                             listen=False)
    return start


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
