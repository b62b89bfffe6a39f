"""Reads that share one transaction (issue 27): `cache = { ttl, serve-stale }` on line serial
and on a route to another line.  Many clients polling one range cost the line at most one
read per ttl and nobody gets data older than ttl; a write makes the next read go to the line;
two identical reads close together are one frame on the line; a silent slave's data is served
stale up to serve-stale, then 0x0B; a request the firewall refuses never gets cached data;
the figures in status, /metrics and the trace; a serial scenario's read fills the cache, a
reload that changes `cache` empties it, and a serial master's write (through a serial face)
drops what a line's cache kept.

Peers that are not ours: pymodbus RTU slaves on socat ptys (tests/peers/pymodbus_slave.py,
with --stamp each read on the line puts its own count in the registers; its record is the
wire), pymodbus's TCP client, raw sockets, raw RTU frames as the serial master;
tests/peers/fault_slave.py for a slave that answers late."""
import re
import struct
import threading
import time
import urllib.request
from pathlib import Path

import pytest
from prometheus_client import parser
from pymodbus.client import ModbusTcpClient

from tests.harness import PtyPair, free_port
from tests.integration.master.test_serial_faces import ask as serial_ask
from tests.integration.master.test_serial_faces import read, write_multiple
from tests.integration.ops.test_reload import reload
from tests.modbus import mbap, read_holding
from tests.ops import metric_families, metric_value, status, tracing, wait_for
from tests.wait import until

pytestmark = pytest.mark.integration

UNIT = 5
METER = 1                       # on line meters, reached as unit 32
STOUT_MS = 300
POLL_FOR_S = 2.0                # four times the ttl of the test of a cache under pollers


def rx(record: Path) -> list[tuple[float, bytes]]:
    """What the recording pymodbus slave received: (when, address + PDU)."""
    if not record.exists():
        return []
    rows = [row.split() for row in record.read_text().splitlines()]
    return [(float(row[0]), bytes.fromhex(row[2])) for row in rows if row[1] == "rx"]


def hr_reply(start: int, count: int) -> bytes:
    """pymodbus_slave.py's holding register n holds 100 + n."""
    return bytes((3, 2 * count)) + b"".join(struct.pack(">H", 100 + start + i)
                                            for i in range(count))


@pytest.fixture
def gateway(tmp_path, pty_pair, start_peer, start_gateway):
    """gateway(toml, *options, peer=(pymodbus_slave.py options)) -> (gw, the slave's
    record): mbgw slave on line serial with toml in its file, a recording pymodbus slave at
    UNIT on the line."""
    def start(toml: str, *options: str, peer=()):
        record = tmp_path / "record.txt"
        start_peer("pymodbus_slave.py", pty_pair.device, str(UNIT), "--silent-unknown",
                   "--record", str(record), *peer)
        path = tmp_path / "mbgw.toml"
        path.write_text(toml)
        gw = start_gateway(pty_pair.gateway, "--config", str(path), "--baudrate", "19200",
                           "--stout", str(STOUT_MS), *options)
        return gw, record
    return start


@pytest.fixture
def meters(tmp_path, start_peer):
    """(line meters' pty pair, its slave's record): a recording pymodbus slave at METER on a
    pty pair of its own."""
    (tmp_path / "meters").mkdir()
    pair = PtyPair(tmp_path / "meters")
    record = tmp_path / "meters.txt"
    start_peer("pymodbus_slave.py", pair.device, str(METER), "--silent-unknown",
               "--record", str(record))
    yield pair, record
    pair.stop()


def meters_line(pair: PtyPair, keys: str = "") -> str:
    """The [[line]] of line meters, with keys of its own."""
    return (f'[[line]]\nname = "meters"\ndevice = "{pair.gateway}"\nbaudrate = 19200\n'
            f'stout = {STOUT_MS}\n{keys}')


def ask(sock_client, tid: int, unit: int, pdu: bytes) -> bytes:
    sock_client.send(mbap(tid, unit, pdu))
    reply = sock_client.recv()
    assert reply is not None and reply[:2] == (tid, unit), reply
    return reply[2]


@pytest.mark.serial
def test_five_clients_at_20_hz_cost_the_line_two_reads_a_second_of_fresh_data(gateway):
    gw, record = gateway("[serial]\ncache = { ttl = 500 }\n", peer=("--stamp",))
    got: list[tuple[float, int]] = []      # (when a client had it, the stamp: which read)
    errors: list[BaseException] = []
    stop_at = time.monotonic() + POLL_FOR_S

    def poll() -> None:
        client = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=3, retries=0)
        try:
            assert client.connect()
            next_at = time.monotonic()
            while next_at < stop_at:
                reply = client.read_holding_registers(0, count=10, device_id=UNIT)
                assert not reply.isError(), reply
                assert len(set(reply.registers)) == 1, reply.registers
                got.append((time.monotonic(), reply.registers[0]))
                next_at += 0.05                         # 20 Hz, the pace of a poller
                time.sleep(max(0.0, next_at - time.monotonic()))
        except BaseException as err:
            errors.append(err)
        finally:
            client.close()

    threads = [threading.Thread(target=poll) for _ in range(5)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors
    reads = [(when, adu) for when, adu in rx(record)
             if adu == bytes((UNIT,)) + read_holding(0, 10)]
    assert len(got) >= 5 * POLL_FOR_S * 15              # they did poll at about 20 Hz
    span_s = reads[-1][0] - reads[0][0]
    assert len(reads) <= 2 * span_s + 1, (len(reads), span_s)     # 2 a second at most
    read_at = [when for when, _ in reads]               # stamp n: the n-th read on the line
    one_transaction_s = STOUT_MS / 1000
    for had_at, stamp in got:
        assert had_at - read_at[stamp - 1] <= 0.5 + one_transaction_s, (stamp, had_at)
    s = status(gw)
    figures = s["lines"][0]["cache"]["units"][str(UNIT)]
    assert figures["misses"] == len(reads)
    assert figures["hits"] + figures["coalesced"] + figures["misses"] == len(got)


def test_a_write_makes_the_next_read_go_to_the_line_with_the_new_value(gateway, client):
    gw, record = gateway("[serial]\ncache = { ttl = 60000 }\n")
    c = client(gw)
    assert ask(c, 1, UNIT, read_holding(0, 10)) == hr_reply(0, 10)
    assert ask(c, 2, UNIT, read_holding(2, 3)) == hr_reply(2, 3)     # a sub-range: memory
    write = struct.pack(">BHHB", 0x10, 5, 2, 4) + struct.pack(">HH", 7, 8)
    assert ask(c, 3, UNIT, write) == struct.pack(">BHH", 0x10, 5, 2)
    expected = bytearray(hr_reply(0, 10))
    expected[2 + 10:2 + 14] = struct.pack(">HH", 7, 8)
    assert ask(c, 4, UNIT, read_holding(0, 10)) == bytes(expected)
    assert [adu for _, adu in rx(record)] == [bytes((UNIT,)) + read_holding(0, 10),
                                             bytes((UNIT,)) + write,
                                             bytes((UNIT,)) + read_holding(0, 10)]
    assert ask(c, 5, UNIT, read_holding(0, 10)) == bytes(expected)   # memory again
    assert len(rx(record)) == 3


def test_two_identical_reads_1_ms_apart_are_one_frame_on_the_line(
        tmp_path, pty_pair, recording_peer, start_gateway, client):
    # fault_slave.py answers address 3 after --late-ms: the first read is on the line
    record = recording_peer("fault_slave.py", "--late-ms", "100")
    path = tmp_path / "mbgw.toml"
    path.write_text("[serial]\ncache = { ttl = 0 }\n")
    gw = start_gateway(pty_pair.gateway, "--config", str(path), "--stout", "500")
    first, second = client(gw), client(gw)
    first.send(mbap(7, 3, read_holding(0, 4)))
    until(lambda: "rx " in record.read_text() if record.exists() else False,
          "the first read on the line", 5)
    second.send(mbap(9, 3, read_holding(0, 4)))
    a, b = first.recv(), second.recv()
    assert a is not None and b is not None
    assert (a[0], b[0]) == (7, 9) and a[2] == b[2] and a[2][:2] == b"\x03\x08"
    frames = [row for row in record.read_text().splitlines() if " rx " in row]
    assert len(frames) == 1, frames
    figures = status(gw)["lines"][0]["cache"]["units"]["3"]
    assert (figures["misses"], figures["coalesced"]) == (1, 1)


@pytest.mark.serial
def test_a_silent_slave_s_data_is_served_stale_up_to_serve_stale_then_0x0b(
        tmp_path, pty_pair, start_peer, start_gateway, client):
    record = tmp_path / "record.txt"
    slave = start_peer("pymodbus_slave.py", pty_pair.device, str(UNIT), "--silent-unknown",
                       "--record", str(record))
    path = tmp_path / "mbgw.toml"
    path.write_text("[serial]\ncache = { ttl = 50, serve-stale = 1500 }\n")
    gw = start_gateway(pty_pair.gateway, "--config", str(path), "--baudrate", "19200",
                       "--stout", "100", "--exception")
    c = client(gw)
    assert ask(c, 1, UNIT, read_holding(0, 4)) == hr_reply(0, 4)
    read_at = rx(record)[0][0]
    slave.stop()
    tid = 1
    replies = []

    def until_0x0b() -> bool:
        nonlocal tid
        tid += 1
        sent_at = time.monotonic()
        reply = ask(c, tid, UNIT, read_holding(1, 2))
        replies.append((sent_at, time.monotonic(), reply))
        return reply == b"\x83\x0b"

    until(until_0x0b, "0x0B", 10)
    served = [reply for _, _, reply in replies[:-1]]
    assert served and all(reply == hr_reply(1, 2) for reply in served), replies
    # the data ended after read_at (when the slave had the request): 0x0B came only once it
    # was older than serve-stale; the last stale answer was asked for before that
    assert replies[-1][1] - read_at >= 1.5
    assert replies[-2][0] - read_at <= 1.5 + 0.05
    figures = status(gw)["lines"][0]["cache"]["units"][str(UNIT)]
    # the first ones may still be fresh (ttl 50 ms), the rest stale
    assert figures["stale_served"] > 0
    assert figures["stale_served"] + figures["hits"] == len(served)


def test_a_request_the_firewall_refuses_gets_no_cached_data(gateway, client):
    rules = ('[firewall]\ndefault = "allow"\n[[rule]]\nclient = "127.0.0.1"\n'
             'registers = "0-3"\n')
    gw, record = gateway("[serial]\ncache = { ttl = 60000 }\n" + rules)
    c = client(gw)
    assert ask(c, 1, UNIT, read_holding(0, 4)) == hr_reply(0, 4)
    assert ask(c, 2, UNIT, read_holding(0, 4)) == hr_reply(0, 4)       # memory
    assert ask(c, 3, UNIT, read_holding(2, 4)) == b"\x83\x01"          # refused
    assert len(rx(record)) == 1


def test_the_figures_in_status_metrics_and_the_trace(gateway, client, tmp_path):
    port = free_port()
    gw, _ = gateway("[serial]\ncache = { ttl = 60000 }\n", "--metrics", f"127.0.0.1:{port}")
    c = client(gw)
    with tracing(gw, tmp_path / "trace.pcap", 4) as (trace, _):
        ask(c, 1, UNIT, read_holding(0, 4))
        ask(c, 2, UNIT, read_holding(0, 4))
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    replies = [row for row in out.decode().splitlines() if " reply " in row]
    assert len(replies) == 2 and "cached" not in replies[0], out
    assert re.search(r"cached \d+ ms", replies[1]), replies
    s = wait_for(gw, lambda s: "cache" in s["lines"][0], "the cache's figures")
    assert s["lines"][0]["cache"]["units"][str(UNIT)] == {
        "hits": 1, "coalesced": 0, "misses": 1, "stale_served": 0}
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    families = metric_families(parser, text)
    assert metric_value(families, "mbgw_cache_requests", "mbgw_cache_requests_total",
                        line="serial", unit=str(UNIT), outcome="hits") == 1
    assert metric_value(families, "mbgw_cache_served_age_seconds",
                        "mbgw_cache_served_age_seconds_count", line="serial") == 1


def test_a_route_s_cache_to_another_line(tmp_path, pty_pair, meters, start_gateway, client):
    pair, record = meters
    path = tmp_path / "mbgw.toml"
    path.write_text(meters_line(pair) + '[[route]]\nunits = "1-31"\nline = "serial"\n'
                    '[[route]]\nunits = "32-63"\nline = "meters"\noffset = -31\n'
                    'cache = { ttl = 60000 }\n')
    gw = start_gateway(pty_pair.gateway, "--config", str(path), "--stout", "300")
    c = client(gw)
    for tid in (1, 2, 3):
        assert ask(c, tid, 32, read_holding(0, 4)) == hr_reply(0, 4)
    assert len(rx(record)) == 1
    row = status(gw)["lines"][1]
    assert row["name"] == "meters" and row["cache"]["units"][str(METER)]["hits"] == 2


def test_a_scenario_s_read_fills_the_cache_and_a_reload_that_changes_it_empties_it(
        gateway, client, tmp_path):
    scenario = ('[[scenario]]\nname = "poll"\nslave = 5\nfunction = 3\naddress = 0\n'
                'quantity = 10\ntable = 0\ncycle = 65535\n')
    gw, record = gateway("[serial]\ncache = { ttl = 600000 }\n" + scenario)
    until(lambda: len(rx(record)) == 1, "the scenario's read on the line", 5)
    c = client(gw)
    assert ask(c, 1, UNIT, read_holding(2, 3)) == hr_reply(2, 3)     # the scenario's data
    assert len(rx(record)) == 1
    path = tmp_path / "mbgw.toml"
    path.write_text(path.read_text().replace("ttl = 600000", "ttl = 500000"))
    reload(gw, "configuration reloaded")
    assert ask(c, 2, UNIT, read_holding(2, 3)) == hr_reply(2, 3)
    assert [adu for _, adu in rx(record)][1:] == [bytes((UNIT,)) + read_holding(2, 3)]


def test_a_serial_master_s_write_drops_what_the_line_s_cache_kept(
        tmp_path, pty_pair, meters, start_gateway, open_line):
    pair, record = meters
    path = tmp_path / "mbgw.toml"
    path.write_text(meters_line(pair, 'cache = { ttl = 600000 }\n')
                    + '[[route]]\nfrom = "serial"\nunits = "32-63"\nline = "meters"\n'
                    'offset = -31\n')
    gw = start_gateway(pty_pair.gateway, "--config", str(path), "--baudrate", "19200",
                       "--exception", mode="master", listen=False)
    master = open_line(pty_pair.device)
    serial_ask(master, read(32, 0, 4), bytes((32,)) + hr_reply(0, 4))
    serial_ask(master, read(32, 1, 2), bytes((32,)) + hr_reply(1, 2))      # memory
    serial_ask(master, write_multiple(32, 2, 7), bytes.fromhex("20 10 0002 0001"))
    expected = bytearray(hr_reply(0, 4))
    expected[2 + 4:2 + 6] = struct.pack(">H", 7)
    serial_ask(master, read(32, 0, 4), bytes((32,)) + bytes(expected))
    assert [adu for _, adu in rx(record)] == [
        bytes((METER,)) + read_holding(0, 4), bytes((METER,)) + write_multiple(1, 2, 7)[1:],
        bytes((METER,)) + read_holding(0, 4)]
    row = next(r for r in status(gw)["lines"] if r["name"] == "meters")
    assert row["cache"]["units"][str(METER)] == {
        "hits": 1, "coalesced": 0, "misses": 2, "stale_served": 0}
