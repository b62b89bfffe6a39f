"""`mbgw scan` and `mbgw probe` on a bus of real peers (issue 29).

The bus is tests/peers/settings_bus.py: a pty the peer makes itself, whose slaves answer only
while the gateway's side of the pty is at their own baud rate and format.  A pty carries no
bits, so the peer reads the settings mbgw made from the pty's master (its docstring says what
carries over on Linux: the speed, odd parity and the stop bits; even parity reads as none,
so these tests never ask for 8e1).  Unit 2 answers FC 17 itself; unit 3 is pymodbus 3.16.1's
RTU server (peers/pymodbus_slave.py --identity) behind the peer, answering FC 43/14; unit 4
has no identity.  The delays are each slave's own; on a pty the reply also comes sooner than
on a wire would by the request's transmission time, which mbgw counts as sent.
"""
import json
import math
import os
import re
import subprocess
import sys

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from tests.harness import PtyPair
from tests.ops import mbgw

pytestmark = pytest.mark.integration

KEYS = {"unit", "baudrate", "format", "exception", "p50_ms", "p99_ms", "identity"}
# (unit, baud rate, format, delay ms): the slaves of the bus
SLOW = (4, 19200, "8n1", 700)
FAST = (2, 9600, "8o1", 20)
MIDDLE = (3, 19200, "8n1", 150)
SETTINGS = ("--baudrates", "9600,19200", "--formats", "8n1,8o1")


@pytest.fixture
def bus(tmp_path, start_peer):
    """bus(*units) -> (device, record path): the settings bus with these slaves; unit 3
    relays to a pymodbus slave on a socat pair."""
    def start(*units: tuple[int, int, str, int]) -> tuple[str, str]:
        record = str(tmp_path / "bus.rec")
        args = [str(tmp_path / "ttyBUS"), "--record", record]
        for unit, baud, fmt, delay in units:
            identity = {2: "fc17", 4: "none"}.get(unit)
            if identity is None:
                pair = PtyPair(tmp_path)
                pairs.append(pair)
                start_peer("pymodbus_slave.py", pair.device, str(unit), "--identity",
                           "--silent-unknown")
                identity = f"relay={pair.gateway}"
            args += ["--unit", f"{unit},{baud},{fmt},{delay},{identity}"]
        start_peer("settings_bus.py", *args)
        return args[0], record
    pairs: list[PtyPair] = []
    yield start
    for pair in pairs:
        pair.stop()


def requests(record: str) -> list[tuple[int, str, int, int]]:
    """What the bus heard: (baud, format, unit, function) per request."""
    rows = []
    for line in open(record):
        _, _, baud, shape, *frame = line.split()
        rows.append((int(baud), shape, int(frame[0], 16), int(frame[1], 16)))
    return rows


def test_scan_finds_each_unit_at_its_settings_with_its_timing_and_identity(bus):
    device, record = bus(FAST, MIDDLE, SLOW)
    done = mbgw("scan", device, *SETTINGS, "--units", "2-5", "--timeout", "800", "--json",
                timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""             # no progress when stderr is no terminal
    found = json.loads(done.stdout)
    assert all(set(row) == KEYS for row in found)
    assert [(r["unit"], r["baudrate"], r["format"], r["exception"]) for r in found] == [
        (2, 9600, "8o1", None), (3, 19200, "8n1", None), (4, 19200, "8n1", None)]
    fast, middle, slow = found
    assert fast["identity"] == {"server_id": "2a 53 43 52 49 50 54 45 44 2d 53 4c 41 56 45 ff",
                                "text": "*SCRIPTED-SLAVE."}
    assert middle["identity"] == {"vendor": "mbgw test vendor", "product_code": "PEER-17",
                                  "revision": "3.16.1"}
    assert slow["identity"] is None
    # each at least its delay less the request's time on the wire (9.2 ms at 9600 Bd)
    assert 20 - 10 < fast["p50_ms"] <= fast["p99_ms"] < 100 < 150 - 5 < middle["p50_ms"] \
        <= middle["p99_ms"] < 700 - 5 < slow["p50_ms"] <= slow["p99_ms"]
    heard = requests(record)
    # an address found is not asked again at the other settings; the timing reads (5) and
    # the identity (FC 43, then FC 17 when 43 fails) at the settings it answered
    assert [(b, f, fc) for b, f, u, fc in heard if u == 2] == [
        (9600, "8n1", 3), (9600, "8o1", 3), *[(9600, "8o1", 3)] * 5, (9600, "8o1", 0x2B),
        (9600, "8o1", 0x11)]
    assert [(b, f, fc) for b, f, u, fc in heard if u == 3][-7:] == [
        *[(19200, "8n1", 3)] * 6, (19200, "8n1", 0x2B)]
    assert {(b, f) for b, f, u, fc in heard if u == 5} == {
        (9600, "8n1"), (9600, "8o1"), (19200, "8n1"), (19200, "8o1")}
    # baud rate, then format, then unit
    order = [(b, f) for b, f, u, fc in heard]
    assert order == sorted(order, key=lambda s: (s[0], s[1] != "8n1"))


def test_scan_first_prints_the_first_unit_found_with_progress_on_a_terminal(bus):
    device, record = bus(FAST, MIDDLE)
    terminal, terminal_end = os.openpty()
    done = subprocess.run([sys.executable, "-m", "mbgw", "scan", device, *SETTINGS,
                           "--units", "2-5", "--timeout", "200", "--first"],
                          stdout=subprocess.PIPE, stderr=terminal_end, text=True, timeout=30)
    os.close(terminal_end)
    shown = os.read(terminal, 65536).decode()
    os.close(terminal)
    assert done.returncode == 0
    assert re.fullmatch(r"unit 2: 9600 8o1, p50 \d+\.\d ms, p99 \d+\.\d ms, server_id "
                        r"'2a 53 [0-9a-f ]+ ff', text '\*SCRIPTED-SLAVE\.'\n", done.stdout)
    assert "\r" in shown and "9600 8n1: unit 5, 0 found" in shown
    assert "19200" not in shown
    assert {u for b, f, u, fc in requests(record)} == {2, 3, 4, 5}    # none after unit 2's
    assert requests(record)[-1][2:] == (2, 0x11)


def _recommended(p99_ms: float) -> int:
    return max(20, math.ceil(p99_ms * 1.5))


@pytest.mark.serial          # it measures the devices' reply times
@pytest.mark.parametrize("unit", [FAST, MIDDLE, SLOW], ids=["20ms", "150ms", "700ms"])
def test_probe_recommends_a_stout_from_the_p99(bus, unit):
    device, _ = bus(unit)
    address, baud, fmt, delay = unit
    count = 10 if delay < 700 else 4
    units = f"{address},5" if unit == FAST else str(address)   # 5: silent, asked once a run
    # above the bound on the p99 asserted below; each read of the silent unit costs twice this
    timeout_ms = {20: 150, 150: 300, 700: 900}[delay]
    done = mbgw("probe", device, "--units", units, "--baudrate", str(baud),
                "--format", fmt, "--count", str(count), "--timeout", str(timeout_ms),
                timeout=30)
    assert done.returncode == 0, done.stderr
    rows = done.stdout.splitlines()
    match = re.fullmatch(rf"unit {address}: {count} reads, {count} answered, p50 (\S+) ms, "
                         r"p99 (\S+) ms, recommended stout (\d+) ms", rows[0])
    assert match, rows
    p50, p99, stout = float(match[1]), float(match[2]), int(match[3])
    assert delay - 10 < p50 <= p99 < delay + 100
    assert stout == _recommended(p99)
    if p99 * 1.5 >= 20:
        assert p99 * 1.2 <= stout <= math.ceil(p99 * 1.5)
    if unit == FAST:
        assert rows[1] == f"unit 5: {count} reads, 0 answered"


@pytest.mark.serial          # a reply 200 ms after its read gave up
def test_a_late_reply_is_never_taken_for_the_next_reads(bus):
    """The 700 ms slave probed with a 500 ms timeout: each reply comes after its read gave
    up.  Taken for the next read (sent at once, as RTU has no transaction id), it would count
    as an answer in about 200 ms; probe waits the late reply out instead."""
    device, record = bus(SLOW)
    address, baud, fmt, _ = SLOW
    done = mbgw("probe", device, "--units", str(address), "--baudrate", str(baud), "--format",
                fmt, "--count", "3", "--timeout", "500", timeout=30)
    assert done.returncode == 1, done.stderr
    assert done.stdout == f"unit {address}: 3 reads, 0 answered\n"
    assert len(requests(record)) == 3


def test_probe_json(bus):
    device, _ = bus(FAST)
    done = mbgw("probe", device, "--units", "2", "--format", "8o1", "--count", "3", "--json")
    assert done.returncode == 0, done.stderr
    [row] = json.loads(done.stdout)
    assert set(row) == {"unit", "reads", "answered", "p50_ms", "p99_ms", "stout_ms"}
    assert (row["unit"], row["reads"], row["answered"]) == (2, 3, 3)
    assert row["stout_ms"] == _recommended(row["p99_ms"])


@pytest.mark.serial          # the requests' times, to a few ms
def test_an_empty_bus_takes_at_most_units_times_the_timeout_and_exits_1(bus):
    device, record = bus()
    units, timeout_ms = 10, 50
    done = CliRunner().invoke(main, ["scan", device, "--baudrates", "9600", "--formats",
                                     "8n1", "--units", f"1-{units}", "--timeout",
                                     str(timeout_ms), "--json"])
    assert done.exit_code == 1
    assert json.loads(done.stdout.splitlines()[0]) == []
    assert f"mbgw: no address answered on {device}" in done.output
    assert [u for b, f, u, fc in requests(record)] == list(range(1, units + 1))
    # the contract's bound: each timeout counts from its request's start, so the requests
    # follow each other a timeout apart (counting from the request's end, as a gateway's
    # stout does, would add 9 ms each at 9600 Bd; the margin is half a timeout in all)
    sent = [float(line.split()[0]) for line in open(record)]
    assert (sent[-1] - sent[0]) * 1000 <= (units - 1) * timeout_ms + timeout_ms / 2


def test_probe_of_silent_units_exits_1(bus):
    device, _ = bus()
    done = mbgw("probe", device, "--units", "7", "--count", "2", "--timeout", "50")
    assert done.returncode == 1
    assert done.stdout == "unit 7: 2 reads, 0 answered\n"
    assert done.stderr == f"mbgw: no address answered on {device}\n"


@pytest.mark.parametrize("args", [
    ("scan", "--units", "0-3"), ("scan", "--units", "1-300"), ("scan", "--formats", "9x1"),
    ("scan", "--baudrates", "fast"), ("scan", "--baudrates", "10"), ("scan", "--timeout", "0"),
    ("probe",), ("probe", "--units", "1", "--format", "8q1"),
])
def test_bad_usage_exits_2_before_the_device_is_opened(tmp_path, args):
    command, *options = args
    done = mbgw(command, str(tmp_path / "none"), *options)
    assert done.returncode == 2, done.stderr
    assert "Error" in done.stderr and "No such file" not in done.stderr


def test_a_device_in_use_by_a_running_gateway_exits_1_naming_it(pty_pair, start_gateway):
    gw = start_gateway(pty_pair.gateway)
    for command in (["scan", pty_pair.gateway, "--units", "1"],
                    ["probe", pty_pair.gateway, "--units", "1"]):
        done = mbgw(*command)
        assert done.returncode == 1
        assert done.stdout == ""
        assert done.stderr.startswith(f"mbgw: {pty_pair.gateway} is in use by pid "
                                      f"{gw.proc.pid} (mbgw slave --device "
                                      f"{pty_pair.gateway} "), done.stderr
