"""`mbgw trace --raw` (issue 25): the serial line's bytes as bursts, each marked, checked
against what the peer on the other end of the socat pty recorded it received and sent
(tests/peers/fault_slave.py: address 1 answers, 2 is silent, 15 answers with garbage only,
as a device at the wrong baud rate does).  And the device's health telling garbage from
silence."""
import subprocess
import sys

import pytest

from tests.harness import _read_lines_until
from tests.integration.slave.test_faults import received
from tests.modbus import crc16, holding_reply, read_holding
from tests.ops import devices, mbgw, status, wait_for, wait_for_log

pytestmark = pytest.mark.integration

GARBAGE = bytes.fromhex("55 aa 55")       # what the fault peer's address 15 sends


def sent_by_peer(record) -> list[bytes]:
    return [bytes.fromhex(line.split(" ", 2)[2]) for line in record.read_text().splitlines()
            if line.split(" ", 2)[1] == "tx"]


class Trace:
    """`mbgw trace ARGS` running on gw's control socket; lines() reads its output."""

    def __init__(self, gw, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "mbgw", "trace", *args,
                                      "--control", gw.control],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.seen: list[str] = []
        self.header = self.lines(1)[0]      # once the daemon has taken the subscription

    def lines(self, count: int) -> list[str]:
        self.seen += _read_lines_until(self.proc, self.proc.stdout,
                                       lambda ls: len(self.seen) + len(ls) >= count, 10)
        return self.seen

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def fault_line(recording_peer):
    """fault_line(*options) -> the record of the fault peer's frames."""
    def start(*options: str):
        return recording_peer("fault_slave.py", *options)
    return start


@pytest.fixture
def gw(pty_pair, start_gateway):
    return start_gateway(pty_pair.gateway, "--stout", "100", "--retries", "0",
                         "--exception")


def bursts(lines: list[str]) -> list[tuple[str, str, bytes]]:
    """(gap, kind, bytes) of the raw trace's lines after its header."""
    out = []
    for line in lines[1:]:
        _, gap, kind, length, *data = line.split()
        hexed = bytes.fromhex("".join(data))
        assert int(length) == len(hexed), line
        out.append((gap, kind, hexed))
    return out


def test_raw_trace_shows_request_reply_and_garbage_as_they_went_on_the_wire(
        fault_line, gw, client, trace):
    record = fault_line()
    t = trace(gw, "--raw")
    assert t.header.split() == ["TIME", "GAP", "us", "KIND", "LEN", "BYTES", "(hex)"]
    c = client(gw)
    assert c.ask(1, read_holding(0, 2)) == holding_reply(0, 2)
    assert c.ask(15, read_holding(0, 1)) == bytes.fromhex("83 0b")    # no valid reply
    shown = bursts(t.lines(5))
    to_peer = [frame for _, frame in received(record)]
    request_1 = bytes.fromhex("01 03 0000 0002")
    request_15 = bytes.fromhex("0f 03 0000 0001")
    assert to_peer == [request_1 + crc16(request_1), request_15 + crc16(request_15)]
    assert [(kind, data) for _, kind, data in shown] == [
        ("request", to_peer[0]), ("reply", sent_by_peer(record)[0]),
        ("request", to_peer[1]), ("noise", GARBAGE)]
    gaps = [gap for gap, _, _ in shown]
    assert gaps[0] == "-" and all(g.isdigit() for g in gaps[1:]), gaps
    # the next request waited for t3.5 (3.6 ms at the default 9600 baud) after the reply
    assert int(gaps[2]) >= 3600, gaps


def test_nobody_watching_the_raw_line_costs_no_capture(fault_line, gw, client, trace):
    """A raw trace that ended leaves nothing captured: a new one shows only what came
    after it began."""
    fault_line()
    c = client(gw)
    first = trace(gw, "--raw", "--count", "2")
    assert c.ask(1, read_holding(0, 1)) == holding_reply(0, 1)
    first.lines(3)
    assert first.proc.wait(10) == 0
    assert c.ask(1, read_holding(1, 1)) == holding_reply(1, 1)     # nobody watches
    second = trace(gw, "--raw")
    assert c.ask(1, read_holding(2, 1)) == holding_reply(2, 1)
    shown = bursts(second.lines(3))
    request = bytes.fromhex("01 03 0002 0001")
    assert [(kind, data[:6]) for _, kind, data in shown][0] == ("request", request)


def test_a_device_that_answers_garbage_is_told_from_a_silent_one(fault_line, gw, client):
    fault_line()
    c = client(gw)
    for _ in range(3):
        assert c.ask(15, read_holding(0, 1)) == bytes.fromhex("83 0b")
        assert c.ask(2, read_holding(0, 1)) == bytes.fromhex("83 0b")
    log = wait_for_log(gw, "is down", 2)
    down = {line.split("device ")[1].split(" ")[0]: line for line in log.splitlines()
            if " is down: " in line}
    assert "answers received but not valid (9 bytes): check baud rate, parity, address" \
        in down["15"], down
    assert "not valid" not in down["2"], down
    s = wait_for(gw, lambda s: {2, 15} <= set(devices(s)), "both devices listed")
    assert devices(s)[15]["diagnosis"] == \
        "answers received but not valid (9 bytes): check baud rate, parity, address"
    assert devices(s)[2]["diagnosis"] is None
    assert devices(status(gw))[15]["health"] == "down"
    shown = mbgw("status", "--control", gw.control).stdout.splitlines()
    row = next(i for i, line in enumerate(shown) if line.split()[:2] == ["15", "down"])
    assert shown[row + 1].strip() == "answers received but not valid (9 bytes): check baud " \
        "rate, parity, address", shown
    row = next(i for i, line in enumerate(shown) if line.split()[:2] == ["2", "down"])
    # after the device's row: its learnt timing (issue 29's refined demotion), its next probe
    assert shown[row + 1].strip().startswith("learnt p99 no answer yet, probe timeout"), shown
    assert shown[row + 2].strip().startswith("next probe in"), shown


@pytest.mark.serial
def test_a_slow_device_is_not_taken_for_one_at_the_wrong_baud_rate(fault_line, gw, client):
    """Address 3 answers 150 ms late (stout 100): valid replies, too late; down, and no
    "not valid" said of it."""
    fault_line("--late-ms", "150")
    c = client(gw)
    for _ in range(3):
        assert c.ask(3, read_holding(0, 1)) == bytes.fromhex("83 0b")
    assert "not valid" not in [line for line in wait_for_log(gw, "device 3 is down")
                               .splitlines() if "device 3 is down" in line][0]
    s = wait_for(gw, lambda s: devices(s).get(3, {}).get("late_replies", 0) >= 2,
                 "the late replies counted")
    assert devices(s)[3]["diagnosis"] is None, devices(s)[3]
