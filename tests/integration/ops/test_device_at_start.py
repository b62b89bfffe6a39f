"""The serial device is not there when the gateway starts (a USB adapter plugged in later, its
/dev/serial/by-id link made then), in each mode: the gateway starts all the same, listens,
refuses what needs the line (0x0A with --exception, else silence), says so once in its log
and in `mbgw status`, and opens the device when it appears, as after an unplug.

The device is a socat pty pair (tests/harness.py PtyPair) started only once the gateway runs,
its links made in a directory that did not exist either when the gateway started; behind it
pymodbus 3.16.1's RTU server (peers/pymodbus_slave.py, slave 17: register n holds 100 + n)
or, in master mode, the test as the serial master with pymodbus TCP servers upstream.
"""
import os
import socket
import time

import pytest

from tests.harness import PtyPair, free_port
from tests.integration.master.rig import ask, holding_reply, identity, read_holding, read_pty, rtu
from tests.integration.slave.test_device_loss import (
    PATH_UNAVAILABLE,
    READ_3,
    REPLY_3,
    recv_adu,
    timed_transact,
)
from tests.modbus import mbap
from tests.ops import mbgw, status, wait_for, wait_for_log

pytestmark = pytest.mark.integration

PROMPT_S = 0.3            # "at once": well before stout
STOUT_MS = 1000
RECOVERY_S = 10.0         # served by then once the device is there (the rule: within 0.5 s)
SERVER = "127.0.7.1"      # master mode: pymodbus TCP server, units 1..40


@pytest.fixture
def later(tmp_path):
    """later() -> the PtyPair made now, in tmp_path/usb (a directory made then too); its
    links `gateway` and `device` are tmp_path/usb/ttyGW and ttyDEV.  Stopped after."""
    pairs = []
    directory = tmp_path / "usb"

    def start() -> PtyPair:
        directory.mkdir()
        pairs.append(PtyPair(directory))
        return pairs[-1]

    start.gateway = str(directory / "ttyGW")       # type: ignore[attr-defined]
    yield start
    for pair in pairs:
        pair.stop()


def assert_waiting(gw, device: str) -> None:
    """The log says once that the device is not there; the status says the gateway waits."""
    lines = [line for line in gw.log().splitlines() if "is not there" in line]
    assert len(lines) == 1 and f"serial device {device} is not there: waiting for it" \
        in lines[0] and " WARNING " in lines[0], gw.log()
    s = status(gw)
    assert (s["serial"]["device"], s["serial"]["state"]) == (device, "waiting")
    text = mbgw("status", "--control", gw.control)
    assert text.returncode == 0, text.stderr
    assert f"{device} " in text.stdout
    assert "line down, waiting for the device to appear" in text.stdout


def assert_opened(gw, device: str) -> None:
    wait_for_log(gw, f"serial device {device} is there: opened")
    assert status(gw)["serial"]["state"] == "up"
    assert "lost" not in gw.log() and " ERROR " not in gw.log(), gw.log()


def served_once_there(sock: socket.socket, tid: int) -> None:
    """Ask until a request is served, against RECOVERY_S (0x0A meanwhile, at once)."""
    deadline = time.monotonic() + RECOVERY_S
    while True:
        reply, took = timed_transact(sock, tid, STOUT_MS / 1000 + 2)
        if reply == REPLY_3:
            return
        assert reply == PATH_UNAVAILABLE and took < PROMPT_S, (reply.hex(" "), took)
        assert time.monotonic() < deadline, f"not served {RECOVERY_S} s after the device came"
        tid += 1
        time.sleep(0.02)                      # poll interval, not synchronisation


@pytest.mark.serial
def test_slave_mode_starts_without_its_device_refuses_with_0x0a_then_serves(
        later, start_gateway, start_peer):
    gw = start_gateway(later.gateway, "--baudrate", "19200", "--exception",
                       "--stout", str(STOUT_MS))
    pid = gw.proc.pid
    with socket.create_connection(("127.0.0.1", gw.port)) as sock:
        for tid in (1, 2):
            reply, took = timed_transact(sock, tid, STOUT_MS / 1000 + 2)
            assert reply == PATH_UNAVAILABLE and took < PROMPT_S, (reply.hex(" "), took)
        assert_waiting(gw, later.gateway)
        pair = later()                        # the adapter is plugged in
        start_peer("pymodbus_slave.py", pair.device)
        served_once_there(sock, 3)
        assert timed_transact(sock, 100, STOUT_MS / 1000 + 2)[0] == REPLY_3
    assert gw.proc.poll() is None and gw.proc.pid == pid
    assert_opened(gw, later.gateway)
    assert status(gw)["counters"]["line_down_rejects"] >= 2


def test_slave_mode_without_exception_is_silent_until_the_device_is_there(
        later, start_gateway, start_peer):
    gw = start_gateway(later.gateway, "--baudrate", "19200", "--stout", str(STOUT_MS))
    with socket.create_connection(("127.0.0.1", gw.port)) as sock:
        sock.sendall(mbap(1, 17, READ_3))
        with pytest.raises(socket.timeout):   # no answer at all, and no EOF
            recv_adu(sock, 0.5)
        assert_waiting(gw, later.gateway)
        pair = later()
        start_peer("pymodbus_slave.py", pair.device)
        wait_for_log(gw, "is there: opened")
        sock.sendall(mbap(2, 17, READ_3))
        assert recv_adu(sock, STOUT_MS / 1000 + 2) == mbap(2, 17, REPLY_3)


def test_master_mode_starts_without_its_device_and_serves_the_master_once_it_is_there(
        later, start_gateway, servers_at):
    port, _ = servers_at(SERVER)
    table_port = str(free_port())
    gw = start_gateway(later.gateway, "--baudrate", "19200", "--mdbport", str(port),
                       "--slaveid", f"1 2 1 0 {SERVER}", "--exception", "--table",
                       "--table-address", "10", "--table-port", table_port, mode="master",
                       listen=False)
    assert_waiting(gw, later.gateway)
    # the TCP side does not wait for the line: the table's server answers meanwhile
    with socket.create_connection(("127.0.0.1", int(table_port))) as sock:
        sock.sendall(mbap(7, 1, bytes.fromhex("06 1000 002a")))
        assert recv_adu(sock, 3.0) == mbap(7, 1, bytes.fromhex("06 1000 002a"))
    pair = later()
    fd = os.open(pair.device, os.O_RDWR | os.O_NOCTTY)
    try:
        expected = rtu(holding_reply(1, *identity(SERVER, 1)))
        deadline = time.monotonic() + RECOVERY_S
        while True:                           # nobody reads the line until it is opened
            os.write(fd, rtu(read_holding(1)))
            if read_pty(fd, len(expected), 0.5) == expected:
                break
            assert time.monotonic() < deadline, f"not served {RECOVERY_S} s after"
        ask(fd, read_holding(10, start=0x1000, count=1), expected=holding_reply(10, 42))
    finally:
        os.close(fd)
    assert_opened(gw, later.gateway)


def test_transparent_mode_starts_without_its_device_and_takes_its_frames_once_it_is_there(
        later, start_gateway):
    gw = start_gateway(later.gateway, "--eof", "crlf", "--rx-size", "8", mode="transparent")
    assert_waiting(gw, later.gateway)
    with socket.create_connection(("127.0.0.1", gw.port)) as sock:    # the table answers
        sock.sendall(mbap(1, 1, read_holding(1, count=1)[1:]))
        assert recv_adu(sock, 3.0) == mbap(1, 1, bytes.fromhex("03 02 0000"))
    pair = later()
    wait_for_log(gw, "is there: opened")
    fd = os.open(pair.device, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, b"OK\r\n")
        wait_for(gw, lambda s: s["counters"]["frames_stored"] == 1, "stored the frame")
    finally:
        os.close(fd)
    with socket.create_connection(("127.0.0.1", gw.port)) as sock:     # rx area: the frame
        sock.sendall(mbap(2, 1, bytes.fromhex("03 0000 0002")))
        assert recv_adu(sock, 3.0) == mbap(2, 1, bytes.fromhex("03 04") + b"OK\r\n")
    assert status(gw)["serial"]["state"] == "up"
