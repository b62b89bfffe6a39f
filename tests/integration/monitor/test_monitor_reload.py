"""Monitor lines by reload, and ASCII monitor lines (issue 29): a SIGHUP adds a `[[line]]` in
monitor mode and its `[[monitor]]` maps, moves a map, and removes the line, each in force
without a restart while line serial keeps serving; a line with `protocol = "ascii"` decodes
the bus's ASCII frames and counts a wrong LRC as a CRC error.  The bus is
tests/peers/bus_fanout.py (scripted master and slave, every byte recorded with its writer):
mbgw's end never writes."""
import os
import signal

import pytest

from tests.harness import PtyPair
from tests.integration.monitor.test_monitor_line import (
    End,
    exchange,
    read,
    registers,
    rtu,
    table,
)
from tests.ops import status, wait_for, wait_for_log

pytestmark = pytest.mark.integration

SERIAL = '[serial]\ndevice = "{serial}"\n[table]\nenabled = true\n'
TAP = '[[line]]\nname = "tap"\nmode = "monitor"\ndevice = "{tap}"\nbaudrate = 19200\n{extra}'
MAP = ('[[monitor]]\nline = "tap"\nunit = 7\nfunction = 3\naddress = 100\nquantity = 2\n'
       'table = {table}\n')


@pytest.fixture
def bus(tmp_path, start_peer):
    """(master End, slave End, tap link, record path): the fan-out bus."""
    links = {name: tmp_path / name for name in ("master", "slave", "tap")}
    record = tmp_path / "bus.txt"
    start_peer("bus_fanout.py", *map(str, links.values()), "--record", str(record))
    return End(links["master"]), End(links["slave"]), links["tap"], record


@pytest.fixture
def serial(tmp_path):
    pair = PtyPair(tmp_path)
    yield pair
    pair.stop()


def reload(gw, config, text: str, count: int) -> None:
    config.write_text(text)
    os.kill(gw.proc.pid, signal.SIGHUP)
    log = wait_for_log(gw, "configuration reloaded", count)
    assert "restart" not in log.split("configuration reloaded")[count], log


def tap_row(s: dict) -> dict | None:
    return next((line for line in s["lines"] if line["name"] == "tap"), None)


def test_a_reload_adds_changes_and_removes_a_monitor_line(tmp_path, bus, serial,
                                                          start_gateway):
    master, slave, tap, record = bus
    config = tmp_path / "mbgw.toml"
    base = SERIAL.format(serial=serial.gateway)
    config.write_text(base)
    gw = start_gateway(serial.gateway, "--config", str(config))
    assert tap_row(status(gw)) is None
    # added, with its map: the pairs it hears go to table 0..1
    reload(gw, config, base + TAP.format(tap=tap, extra="") + MAP.format(table=0), 1)
    wait_for(gw, lambda s: tap_row(s) is not None and tap_row(s)["state"] == "up",
             "the monitor line up")
    exchange(master, slave, read(7, 3, 100, 2), registers(7, [11, 22]))
    wait_for(gw, lambda s: tap_row(s)["counters"]["monitor_answered"] == 1, "a pair heard")
    assert table(gw, 0, 2) == [11, 22]
    # the map moved to table 40, the line kept listening (its counters go on)
    reload(gw, config, base + TAP.format(tap=tap, extra="") + MAP.format(table=40), 2)
    exchange(master, slave, read(7, 3, 100, 2), registers(7, [33, 44]))
    wait_for(gw, lambda s: tap_row(s)["counters"]["monitor_answered"] == 2, "a pair heard")
    assert table(gw, 40, 2) == [33, 44] and table(gw, 0, 2) == [11, 22]
    # removed: no longer listened to, its device released
    reload(gw, config, base, 3)
    wait_for(gw, lambda s: tap_row(s) is None, "the monitor line gone")
    wait_for_log(gw, "line tap: no longer listened to")
    writers = {row.split()[0] for row in record.read_text().splitlines()}
    assert writers == {"master", "slave"}           # mbgw's end wrote not one byte
    assert gw.proc.poll() is None


def ascii_frame(adu: bytes, lrc_error: bool = False) -> bytes:
    lrc = (-sum(adu)) & 0xFF
    if lrc_error:
        lrc ^= 0x01
    return b":" + (adu + bytes((lrc,))).hex().upper().encode() + b"\r\n"


def test_an_ascii_monitor_line_decodes_ascii_frames(tmp_path, bus, serial, start_gateway):
    master, slave, tap, record = bus
    config = tmp_path / "mbgw.toml"
    config.write_text(SERIAL.format(serial=serial.gateway)
                      + TAP.format(tap=tap, extra='protocol = "ascii"\n') + MAP.format(table=0))
    gw = start_gateway(serial.gateway, "--config", str(config))
    exchange(master, slave, ascii_frame(bytes.fromhex("07 03 0064 0002")),
             ascii_frame(bytes.fromhex("07 03 04 0001 0002")))
    exchange(master, slave, ascii_frame(bytes.fromhex("07 03 0064 0002")),
             ascii_frame(bytes.fromhex("07 03 04 0003 0004"), lrc_error=True))
    # an RTU frame on an ASCII bus is noise, never a frame; the next pair is heard
    exchange(master, slave, rtu(bytes.fromhex("07 03 0064 0002")), None)
    exchange(master, slave, ascii_frame(bytes.fromhex("07 03 0064 0002")),
             ascii_frame(bytes.fromhex("07 03 04 0005 0006")))
    row = wait_for(gw, lambda s: tap_row(s)["counters"]["monitor_answered"] == 2,
                   "the last pair heard")
    counters = tap_row(row)["counters"]
    # the request the bad reply answered was given up on when the next one came
    assert (counters["monitor_frames"], counters["monitor_crc_errors"],
            counters["monitor_unanswered"]) == (5, 1, 1)
    assert table(gw, 0, 2) == [5, 6]
    writers = {row.split()[0] for row in record.read_text().splitlines()}
    assert writers == {"master", "slave"}
