"""Master mode: the serial device disappears while the gateway runs, and comes back.

`mbgw master` is on one end of a socat pty pair (tests/harness.py PtyPair), the serial master
(raw RTU frames written by the test) on the other, and a pymodbus Modbus TCP server on loopback
(peers/pymodbus_tcp_servers.py) behind the slaveid table.  Stopping socat removes the pty
under the gateway, as unplugging a USB adapter does; starting it again with the same link
names brings the device back at the same path.  The gateway must reopen it on its own, within
0.5 s of its return however long it was away (it looks at the path every 0.1 s and opens
what appears there at once), and log the loss and the return once each.
"""
import os
import time

import pytest

from tests.integration.master.rig import (
    ask,
    holding_reply,
    identity,
    read_holding,
    read_pty,
    rtu,
    wait_for_log,
)

pytestmark = [pytest.mark.integration, pytest.mark.serial]

SERVER = "127.0.7.1"          # answers; units 1..40 and 255
TABLE = "1 2 1 0 " + SERVER   # serial addresses 1, 2 -> SERVER units 1, 2
TCPTO_MS = 500
RECOVERY_S = 10.0             # served again by then, whatever happens
POLL_S = 0.5                  # one attempt of the recovery poll: a reply takes milliseconds
OUTAGE_S = 4.0                # long enough for a backoff from 0.5 s to reach its 2 s and 4 s steps
BACK_WITHIN_S = 1.0           # served again this soon after the device is back (the rule: 0.5 s)


def reply(address: int) -> bytes:
    return holding_reply(address, *identity(SERVER, address))


def open_line(pty_pair) -> int:
    """The serial master's end of the line as a raw fd."""
    return os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)


def served_again(fd: int, address: int, poll_s: float = POLL_S) -> list[bytes]:
    """Ask until the answer comes, against a deadline (each attempt waits poll_s for it):
    until the gateway has reopened the device nobody reads the line.  The requests written
    before that wait in the pty; the reopened gateway takes them all and answers only the last
    (the master has moved on from the others: counted as abandoned).  Returns what came back
    for the attempts that went unanswered (nothing, normally)."""
    want = rtu(reply(address))
    deadline = time.monotonic() + RECOVERY_S
    misses = []
    while True:
        os.write(fd, rtu(read_holding(address)))
        got = read_pty(fd, len(want), poll_s)
        if got == want:
            return misses
        misses.append(got)
        assert time.monotonic() < deadline, \
            f"not served again after {RECOVERY_S} s; got {[m.hex(' ') for m in misses]}"


def test_master_device_loss_recovers_without_restart(pty_pair, servers_at, start_master):
    port, _ = servers_at(SERVER)
    gw = start_master("--mdbport", str(port), "--tcpto", str(TCPTO_MS), "--exception",
                      "--slaveid", TABLE, "--log-level", "debug")
    pid = gw.proc.pid
    lost_text = f"serial device {pty_pair.gateway} lost"
    back_text = f"serial device {pty_pair.gateway} is back"

    fd = open_line(pty_pair)
    try:
        ask(fd, read_holding(1), expected=reply(1))
    finally:
        os.close(fd)

    pty_pair.stop()                           # the device disappears (socat has exited)
    wait_for_log(gw, lost_text)               # the gateway notices on its own, while idle
    assert gw.proc.poll() is None, gw.log()

    pty_pair.start()                          # the device comes back at the same path
    fd = open_line(pty_pair)
    try:
        served_again(fd, 1)
        ask(fd, read_holding(2), expected=reply(2))     # and keeps serving
    finally:
        os.close(fd)

    assert gw.proc.poll() is None and gw.proc.pid == pid, "the gateway was restarted or died"
    lines = gw.log().splitlines()
    lost = [line for line in lines if "serial device" in line and "lost" in line]
    back = [line for line in lines if "serial device" in line and "is back" in line]
    assert len(lost) == 1 and lost_text in lost[0], lines
    assert len(back) == 1 and back_text in back[0], lines
    assert lines.index(lost[0]) < lines.index(back[0]), lines
    assert not [line for line in lines if " ERROR " in line and line != lost[0]], lines


def test_master_device_back_after_a_long_outage_is_served_within_a_second(pty_pair, servers_at,
                                                                          start_master):
    port, _ = servers_at(SERVER)
    gw = start_master("--mdbport", str(port), "--tcpto", str(TCPTO_MS), "--exception",
                      "--slaveid", TABLE)
    fd = open_line(pty_pair)
    try:
        ask(fd, read_holding(1), expected=reply(1))
    finally:
        os.close(fd)

    pty_pair.stop()
    gone = time.monotonic()
    wait_for_log(gw, f"serial device {pty_pair.gateway} lost")
    time.sleep(max(0.0, gone + OUTAGE_S - time.monotonic()))   # the outage, not a wait for it
    pty_pair.start()                          # back at the same path: socat's links exist
    fd = open_line(pty_pair)                  # and the serial master is ready
    try:
        start = time.monotonic()
        served_again(fd, 1, poll_s=0.1)
        took = time.monotonic() - start
    finally:
        os.close(fd)
    assert took < BACK_WITHIN_S, f"served {took:.2f} s after the device came back"
    # an absent device is only looked at: no open attempt to fail, nothing logged
    lines = gw.log().splitlines()
    assert not [line for line in lines if " WARNING " in line or " ERROR " in line
                and "lost" not in line], lines
