"""A listen-only line (`mode = "monitor"`, issue 29): a scripted master and slave on one bus
(tests/peers/bus_fanout.py: three ptys, each end's bytes to the others, who wrote what
recorded) with mbgw's monitor line on it.  The table holds exactly the answered values under
the [[monitor]] maps, a part where a reply covers part of a map; unanswered requests and CRC
errors are counted; mbgw writes nothing on the bus."""
import json
import os
import select
import struct
import subprocess
import time
import tty
from pathlib import Path

import pytest

from tests.harness import PtyPair, free_port
from tests.modbus import rtu_frame as rtu
from tests.ops import (
    mbgw,
    metric_value,
    scraped,
    status,
    tracing,
    tshark_warnings,
    wait_for,
)

pytestmark = pytest.mark.integration

REPLY_S = 5.0
CONFIG = """\
[serial]
mode = "{mode}"
device = "{serial}"

[table]
enabled = true

[[line]]
name = "tap"
mode = "monitor"
device = "{tap}"
baudrate = 19200

[[monitor]]
line = "tap"
unit = 7
function = 3
address = 100
quantity = 4
table = 0

[[monitor]]
line = "tap"
unit = 7
function = 1
address = 0
quantity = 8
table = 10

[[monitor]]
line = "tap"
unit = 9
function = 4
address = 0
quantity = 2
table = 20
"""


def read(unit: int, function: int, start: int, count: int) -> bytes:
    return rtu(struct.pack(">BBHH", unit, function, start, count))


def registers(unit: int, values: list[int]) -> bytes:
    return rtu(struct.pack(f">BBB{len(values)}H", unit, 3, 2 * len(values), *values))


class End:
    """One device on the bus: the test writes what it says and reads what the others do."""

    def __init__(self, link: Path) -> None:
        self.fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)

    def say(self, frame: bytes) -> None:
        os.write(self.fd, frame)

    def hear(self, frame: bytes) -> None:
        """Read what the bus carried until it is frame (the other end's write, whole)."""
        got = b""
        deadline = time.monotonic() + REPLY_S
        while len(got) < len(frame):
            ready, _, _ = select.select([self.fd], [], [], deadline - time.monotonic())
            assert ready, f"heard {got.hex()} of {frame.hex()}"
            got += os.read(self.fd, len(frame) - len(got))
        assert got == frame


def exchange(master: End, slave: End, request: bytes, reply: bytes | None) -> None:
    """The master's request heard by the slave, then its reply (if any) heard by the master:
    so the bus carries them in this order."""
    master.say(request)
    slave.hear(request)
    if reply is not None:
        slave.say(reply)
        master.hear(reply)


# the trace of play_the_bus: 6 requests, 4 replies, 2 given up on, 1 CRC error
TRACE_EVENTS = 13


def play_the_bus(master: End, slave: End) -> None:
    bad = bytearray(registers(7, [9]))
    bad[-1] ^= 0xFF
    exchange(master, slave, read(7, 3, 100, 4), registers(7, [11, 22, 33, 44]))
    exchange(master, slave, read(7, 3, 102, 4), registers(7, [55, 66, 77, 88]))
    exchange(master, slave, read(9, 4, 0, 2), None)              # unanswered
    exchange(master, slave, read(7, 1, 0, 8), rtu(bytes([7, 1, 1, 0b101])))
    exchange(master, slave, read(7, 3, 200, 1), bytes(bad))      # a CRC error
    exchange(master, slave, read(7, 3, 300, 1), registers(7, [99]))   # in no map


def table(gw, address: int, count: int) -> list[int]:
    result = mbgw("table", "read", str(address), str(count), "--json", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)["values"]


@pytest.mark.parametrize("mode", ["slave", "master"])
def test_the_monitor_line_stores_what_the_bus_answers_and_never_writes(
        tmp_path, start_peer, start_gateway, mode: str) -> None:
    links = {name: tmp_path / name for name in ("master", "slave", "tap")}
    record = tmp_path / "bus.txt"
    start_peer("bus_fanout.py", *map(str, links.values()), "--record", str(record))
    serial = PtyPair(tmp_path)
    config = tmp_path / "mbgw.toml"
    config.write_text(CONFIG.format(mode=mode, serial=serial.gateway, tap=links["tap"]))
    metrics_port = free_port()
    options = ("--config", str(config), "--metrics", f"127.0.0.1:{metrics_port}")
    try:
        if mode == "slave":
            gw = start_gateway(serial.gateway, *options)
        else:
            gw = start_gateway(serial.gateway, *options, "--table-port", str(free_port()),
                               mode="master", listen=False)
        master, slave = End(links["master"]), End(links["slave"])
        pcap = tmp_path / "tap.pcap"
        with tracing(gw, pcap, TRACE_EVENTS, "--line", "tap") as (trace, _):
            play_the_bus(master, slave)
            out, err = trace.communicate(timeout=10)
        assert trace.returncode == 0, err
        events = [text.split()[1:] for text in out.decode().splitlines()]
        assert all(e[-2:] == ["line", "tap"] for e in events), events
        assert events[:2] == [
            ["request", "monitor", "(heard)", "-", "7", "0x03", "5", "line", "tap"],
            ["reply", "monitor", "(heard)", "-", "7", "0x03", "10", "reply", "line", "tap"]]
        assert sum(e[-3] == "timeout" for e in events) == 2
        assert ["ignored", "monitor", "(heard)", "-", "7", "0x03", "6", "crc", "error", "line",
                "tap"] in events
        decoded = subprocess.run(["tshark", "-r", str(pcap), "-Y", "mbtcp"],
                                 capture_output=True, text=True, timeout=60)
        assert len(decoded.stdout.splitlines()) == 10, decoded.stdout + decoded.stderr
        assert tshark_warnings(pcap, 502).stdout == ""
        row = wait_for(gw, lambda s: any(
            line["name"] == "tap" and line["counters"]["monitor_frames"] == 10
            for line in s["lines"]), "10 frames heard")
        tap = next(line for line in row["lines"] if line["name"] == "tap")
        assert tap["mode"] == "monitor"
        assert tap["counters"]["monitor_crc_errors"] == 1
        assert tap["counters"]["monitor_unanswered"] == 2     # unit 9's, and the bad reply's
        assert (tap["requests"], tap["replies"], tap["timeouts"]) == (6, 4, 2)
        ages = {m["map"]: m["age_s"] for m in tap["maps"]}
        assert ages[1] is not None and ages[2] is not None and ages[3] is None
        assert table(gw, 0, 4) == [11, 22, 55, 66]
        assert table(gw, 10, 8) == [1, 0, 1, 0, 0, 0, 0, 0]
        assert table(gw, 20, 2) == [0, 0]
        families = scraped(metrics_port)
        assert [metric_value(families, f"mbgw_monitor_{name}", f"mbgw_monitor_{name}_total",
                             line="tap")
                for name in ("frames", "crc_errors", "unanswered")] == [10, 1, 2]
        writers = {row.split()[0] for row in record.read_text().splitlines()}
        assert writers == {"master", "slave"}           # mbgw's end wrote not one byte
        assert status(gw)["lines"][-1]["name"] == "tap"
        text = mbgw("status", "--control", gw.control)
        assert "maps of line tap (3)" in text.stdout, text.stdout + text.stderr
        assert "monitor 3    never stored" in text.stdout
    finally:
        serial.stop()
