"""What the master-mode tests share besides their fixtures (servers_at, start_master and line,
in conftest.py): writing requests on the line and checking what comes back, and the
operator's commands over the control socket.

Readiness is always an event: a server's READY, the gateway's READY=1, a frame back on the
line, a log line, or a condition on the daemon's own status (polled over the control socket
where the daemon does something on its own after the last event a test can see)."""
import os
import time

from tests.harness import read_pty, stop_counters
from tests.integration.master.test_master import (
    BAUD,
    REPLY_S,
    holding_reply,
    identity,
    read_holding,
    rtu,
)
from tests.ops import mbgw, status, wait_for, wait_for_log

__all__ = ["BAUD", "REPLY_S", "holding_reply", "identity", "read_holding", "read_pty", "rtu",
           "ask", "unanswered", "probed", "mbgw", "status", "wait_for", "wait_for_log",
           "stop_counters"]


def ask(fd: int, *frames: bytes, expected: bytes) -> None:
    """Write the requests (ADUs without CRC) on the line; the first frame back must be
    `expected` (an ADU without CRC)."""
    os.write(fd, b"".join(map(rtu, frames)))
    want = rtu(expected)
    got = read_pty(fd, len(want))
    assert got == want, f"wrote {[f.hex(' ') for f in frames]}: got {got.hex(' ')!r}, " \
                        f"expected {want.hex(' ')!r}"


def unanswered(fd: int, *frames: bytes, then: bytes, expected: bytes) -> None:
    """The requests get no answer: the request `then`, written right behind them, gets its
    answer `expected` first."""
    ask(fd, *frames, then, expected=expected)


def probed(fd: int, request: bytes, expected: bytes, refused: bytes) -> int:
    """Write the request on the line until it is answered `expected`: the probe of an address
    that is down.  Every answer before it must be `refused` (the gateway's own, given at
    once).  Returns how many there were."""
    deadline = time.monotonic() + 15 * REPLY_S
    count = 0
    while True:
        os.write(fd, rtu(request))
        got = read_pty(fd, 2)
        if got == rtu(refused)[:2]:
            got += read_pty(fd, len(rtu(refused)) - 2)
            assert got == rtu(refused), got.hex(" ")
            count += 1
            assert time.monotonic() < deadline, f"no probe after {count} refusals"
            continue
        got += read_pty(fd, len(rtu(expected)) - 2)
        assert got == rtu(expected), got.hex(" ")
        return count
