"""Slave mode serves the exchange table (issue 14): which units reach it, that its requests
never wait for the serial line, that a reader never sees half of a write, and that its
transactions are traced.  Peers that are not ours: pymodbus's TCP client and RTU slave, mbpoll,
raw sockets, and the test itself as the serial slave on the pty where the line must be held.

Expected values come from the issue and the Modbus application protocol: the table is 65,536
registers, zero at the start; bit B is bit B % 16 of register B // 16; FC 3 and FC 4 read the
same registers; the configuration zone (0x8000-) is read-only (0x02); a disabled function is
0x01; units 247-254 reach it with direct messaging on, every unit with it off (unit 0 then is
a broadcast write, never answered).
"""
import json
import os
import select
import socket
import struct
import subprocess
import threading

import pytest
from pymodbus.client import ModbusTcpClient

from tests.harness import factory, read_pty
from tests.integration.ops.test_reload import config_set, reload
from tests.modbus import crc16, mbap, read_holding
from tests.ops import mbgw, status, tracing, wait_for

pytestmark = pytest.mark.integration

REPLY_S = 3.0
NO_REPLY_S = 0.5            # how long "no reply" is awaited
LINE_UNIT = 1               # the pymodbus slave: holding register n holds 100 + n


@pytest.fixture
def table_gateway(pty_pair, start_peer, start_gateway):
    """table_gateway(*options, slaves=("1",)) -> a gateway with --table and these options,
    pymodbus RTU slaves at these addresses on its line (silent for the others)."""
    def start(*options: str, slaves=(str(LINE_UNIT),)):
        start_peer("pymodbus_slave.py", pty_pair.device, *slaves, "--silent-unknown")
        return start_gateway(pty_pair.gateway, "--baudrate", "19200", "--table", *options)
    return start


@pytest.fixture
def pymodbus_client():
    """pymodbus_client(gw) -> a connected pymodbus TCP client; closed after the test."""
    def connect(gw) -> ModbusTcpClient:
        c = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0)
        assert c.connect()
        return c

    yield from factory(connect, ModbusTcpClient.close)


def read(c: ModbusTcpClient, address: int, count: int, unit: int) -> list[int]:
    rr = c.read_holding_registers(address, count=count, device_id=unit)
    assert not rr.isError(), rr
    return rr.registers


def reply_to(sock: socket.socket) -> tuple[int, int, bytes]:
    """(tid, unit, pdu) of the next whole MBAP frame."""
    header = recv_exactly(sock, 7)
    tid, protocol, length, unit = struct.unpack(">HHHB", header)
    assert protocol == 0, header.hex(" ")
    return tid, unit, recv_exactly(sock, length - 1)


def recv_exactly(sock: socket.socket, n: int) -> bytes:
    sock.settimeout(REPLY_S)
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        assert chunk, f"connection closed after {data.hex(' ')}"
        data += chunk
    return data


def nothing_waits(sock: socket.socket) -> bool:
    return not select.select([sock], [], [], 0)[0]


# --- who reaches the table ------------------------------------------------------------------

def test_units_247_to_254_reach_the_table_and_the_others_the_line(table_gateway,
                                                                  pymodbus_client):
    c = pymodbus_client(table_gateway())
    assert read(c, 0x1000, 3, 247) == [0, 0, 0]          # the table starts at zero
    assert not c.write_registers(0x1000, [11, 22, 33], device_id=247).isError()
    # one table behind every table unit; FC 4 reads the same registers as FC 3
    assert read(c, 0x1000, 3, 254) == [11, 22, 33]
    rr = c.read_input_registers(0x1001, count=2, device_id=250)
    assert not rr.isError() and rr.registers == [22, 33], rr
    # the serial slave is reached as before, and the table write did not touch it
    assert read(c, 3, 2, LINE_UNIT) == [103, 104]
    # bit 0x21 is bit 1 of register 2
    assert not c.write_coil(0x21, True, device_id=248).isError()
    assert read(c, 2, 1, 248) == [0b10]
    rr = c.read_coils(0x20, count=3, device_id=249)
    assert not rr.isError() and rr.bits[:3] == [False, True, False], rr
    # unit 255 is neither the table's nor a serial address: no reply (no --exception)
    raw = socket.create_connection(("127.0.0.1", c.comm_params.port), timeout=REPLY_S)
    with raw:
        raw.sendall(mbap(7, 255, read_holding(0, 1)))
        assert select.select([raw], [], [], NO_REPLY_S)[0] == []


def test_moved_table_units_free_247_for_the_line(table_gateway, pymodbus_client, client):
    gw = table_gateway("--table-units", "200", "--exception", slaves=("247",))
    c = pymodbus_client(gw)
    assert read(c, 5, 2, 247) == [105, 106]              # the serial slave 247
    assert not c.write_register(0x0800, 0xBEEF, device_id=200).isError()
    assert read(c, 0x0800, 1, 200) == [0xBEEF]
    assert read(c, 5, 1, 247) == [105]
    # 248 is no table unit now: beyond the serial addresses, refused 0x0A
    assert client(gw).ask(248, read_holding(0, 1)) == bytes.fromhex("83 0a")


def test_with_no_direct_every_unit_reaches_the_table_and_unit_0_is_a_broadcast_write(
        table_gateway, client):
    gw = table_gateway("--no-direct")
    c = client(gw)
    # unit 1 is a slave on the line, but the table answers: zero, not 101
    assert c.ask(LINE_UNIT, read_holding(1, 1)) == bytes.fromhex("03 02 0000")
    c.send(mbap(0x0101, 0, bytes.fromhex("06 1234 abcd")))   # FC 6 broadcast
    assert c.recv(NO_REPLY_S) is None
    assert c.ask(5, read_holding(0x1234, 1)) == bytes.fromhex("03 02 abcd")
    assert c.ask(200, bytes.fromhex("04 1234 0001")) == bytes.fromhex("04 02 abcd")


def test_exceptions_reach_the_client(table_gateway, client):
    c = client(table_gateway("--table-functions", "3,4,6,16"))
    assert c.ask(247, bytes.fromhex("01 0000 0008")) == bytes.fromhex("81 01")   # disabled
    assert c.ask(247, bytes.fromhex("06 8000 0001")) == bytes.fromhex("86 02")   # config zone
    assert c.ask(247, bytes.fromhex("03 ffff 0002")) == bytes.fromhex("83 02")   # beyond
    assert c.ask(247, bytes.fromhex("03 0000 007e")) == bytes.fromhex("83 03")   # 126 > 125
    assert c.ask(247, bytes.fromhex("03 0000 0001")) == bytes.fromhex("03 02 0000")


def test_mbpoll_reads_the_table(table_gateway, pymodbus_client):
    gw = table_gateway()
    c = pymodbus_client(gw)
    assert not c.write_registers(0x0900, [7, 8, 9], device_id=247).isError()
    out = subprocess.run(["mbpoll", "-m", "tcp", "-a", "247", "-p", str(gw.port), "-0", "-1",
                          "-t", "4", "-r", str(0x0900), "-c", "3", "127.0.0.1"],
                         capture_output=True, text=True, timeout=10)
    assert out.returncode == 0, out.stdout + out.stderr
    values = {int(ref[1:]): v.strip() for ref, v in
              (line.split("]:", 1) for line in out.stdout.splitlines()
               if line.startswith("[") and "]:" in line)}
    assert values == {0x0900: "7", 0x0901: "8", 0x0902: "9"}


def test_a_table_request_on_an_idle_line_is_answered_from_the_table(table_gateway, client):
    """The first request of a client at rest on an idle line: the shortcut (on by default)
    must not put a table unit on the line."""
    c = client(table_gateway())
    assert c.ask(251, read_holding(0x0800, 2)) == bytes.fromhex("03 04 0000 0000")
    assert c.ask(LINE_UNIT, read_holding(0, 1)) == bytes.fromhex("03 02 0064")
    assert c.ask(247, b"\x07") == bytes.fromhex("07 00")    # FC 7: line up, no device down


# --- a table request never waits for the line -----------------------------------------------

def test_a_table_request_is_answered_while_the_line_waits_out_a_long_stout(
        pty_pair, start_gateway, client):
    """The test is the serial slave: it sees the slow request on the line and never answers
    it, so the line thread is inside its 600 ms wait when the table request comes."""
    line = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)
    try:
        gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--stout", "600",
                           "--exception", "--table")
        slow, fast = client(gw), client(gw)
        slow.send(mbap(0x5101, 5, read_holding(0, 1)))
        frame = bytes((5,)) + read_holding(0, 1)
        assert read_pty(line, len(frame) + 2) == frame + crc16(frame)
        # the line now waits for the silent slave 5: the table answers meanwhile, twice, and
        # a request for the line read meanwhile waits its turn
        fast.send(mbap(0x7701, 247, bytes.fromhex("06 1000 0042")))
        assert fast.recv() == (0x7701, 247, bytes.fromhex("06 1000 0042"))
        assert nothing_waits(slow.sock)
        fast.send(mbap(0x7702, 247, read_holding(0x1000, 1)),
                  mbap(0x7703, 9, read_holding(3, 1)))
        assert fast.recv() == (0x7702, 247, bytes.fromhex("03 02 0042"))
        assert nothing_waits(slow.sock)
        # then the slow request times out, and the one for slave 9 goes on the line
        assert slow.recv() == (0x5101, 5, bytes.fromhex("83 0b"))
        frame = bytes((9,)) + read_holding(3, 1)
        assert read_pty(line, len(frame) + 2) == frame + crc16(frame)
        answer = bytes((9,)) + bytes.fromhex("03 02 1234")
        os.write(line, answer + crc16(answer))
        assert fast.recv() == (0x7703, 9, bytes.fromhex("03 02 1234"))
    finally:
        os.close(line)


def test_a_reader_never_sees_half_of_a_write(pty_pair, start_peer, start_gateway, client):
    """Writers hammer 100 registers with FC 16, each writing them all equal to its own value,
    while readers read them back (and a client keeps the line busy with a silent slave, so
    the table reader serves too): every read sees 100 equal values."""
    start_peer("pymodbus_slave.py", pty_pair.device, "1", "--silent-unknown")
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--stout", "20", "--table",
                       "--exception", "--max-connections", "8", "--down-after", "0")
    rounds, start, count = 1000, 0x2000, 100
    failures: list[str] = []
    lines: list[bytes] = []
    stop = threading.Event()

    def writer(n: int) -> None:
        c = clients[n]
        for i in range(rounds):
            value = (n << 12) | i
            body = struct.pack(">BHHB", 0x10, start, count, 2 * count) + \
                struct.pack(">H", value) * count
            if c.ask(247, body) != struct.pack(">BHH", 0x10, start, count):
                failures.append(f"writer {n}: bad reply")
                return

    def reader(n: int) -> None:
        c = clients[4 + n]
        while not stop.is_set():
            reply = c.ask(248, read_holding(start, count))
            values = struct.unpack(f">{count}H", reply[2:])
            if reply[:2] != bytes((3, 2 * count)) or len(set(values)) != 1:
                failures.append(f"reader {n}: torn read {sorted(set(values))[:4]}")
                return

    def line_load() -> None:
        c = clients[6]
        while not stop.is_set():
            lines.append(c.ask(7, read_holding(0, 1)))    # slave 7 is silent: 0x0B after stout

    clients = [client(gw) for _ in range(7)]
    def failing(work, *args):
        def run() -> None:
            try:
                work(*args)
            except Exception as err:   # a thread's failure is the test's
                failures.append(f"{work.__name__}{args}: {err!r}")
                stop.set()
        return threading.Thread(target=run)

    readers = [failing(reader, n) for n in range(2)]
    writers = [failing(writer, n) for n in range(4)]
    busy = failing(line_load)
    for t in [busy, *readers, *writers]:
        t.start()
    for t in writers:
        t.join()
    stop.set()
    for t in [busy, *readers]:
        t.join()
    assert not failures, failures
    assert lines and set(lines) == {bytes.fromhex("83 0b")}


# --- the trace ------------------------------------------------------------------------------

def test_the_trace_shows_table_transactions(table_gateway, client, tmp_path):
    gw = table_gateway()
    with tracing(gw, tmp_path / "t.pcap", count=2) as (trace, _):
        c = client(gw)
        assert c.ask(247, read_holding(0, 1)) == bytes.fromhex("03 02 0000")
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    rows = [line.split() for line in out.decode().splitlines()]
    assert [row[1] for row in rows] == ["request", "reply"], out
    assert rows[1][4:7] == ["247", "0x03", "4"], out
    assert rows[1][7] == "table", out


# --- reload ---------------------------------------------------------------------------------

def test_a_reload_turns_the_table_on_moves_its_units_and_turns_it_off_on_the_same_connection(
        reloadable):
    path, gw, c = reloadable(LINE_UNIT)
    assert c.ask(247, read_holding(0, 1)) == bytes.fromhex("83 0b")     # the line's: silent
    config_set(path, "table", "enabled", "on")
    reload(gw, "configuration reloaded: table changed")
    assert c.ask(247, bytes.fromhex("06 0000 0007")) == bytes.fromhex("06 0000 0007")
    assert c.ask(LINE_UNIT, read_holding(0, 1)) == bytes.fromhex("03 02 0064")
    config_set(path, "table", "units", "200")
    reload(gw, "configuration reloaded: table changed", count=2)
    assert c.ask(247, read_holding(0, 1)) == bytes.fromhex("83 0b")
    assert c.ask(200, read_holding(0, 1)) == bytes.fromhex("03 02 0007")   # the same table
    config_set(path, "table", "functions", "4")
    reload(gw, "configuration reloaded: table changed", count=3)
    assert c.ask(200, read_holding(0, 1)) == bytes.fromhex("83 01")
    assert c.ask(200, bytes.fromhex("04 0000 0001")) == bytes.fromhex("04 02 0007")
    config_set(path, "table", "enabled", "off")
    reload(gw, "configuration reloaded: table changed", count=4)
    assert c.ask(200, read_holding(0, 1)) == bytes.fromhex("83 0b")     # the line's: silent
    assert c.ask(LINE_UNIT, read_holding(0, 1)) == bytes.fromhex("03 02 0064")


# --- the operator: configuration zone, table read/write, status, persistence ----------------

@pytest.mark.usefixtures("state_directory")
def test_the_operator_reads_and_writes_the_table_sees_its_figures_and_it_survives_a_restart(
        tmp_path, pty_pair, start_peer, start_gateway, client):
    start_peer("pymodbus_slave.py", pty_pair.device, str(LINE_UNIT), "--silent-unknown")
    keep = tmp_path / "table.bin"
    options = ("--baudrate", "19200", "--table", "--table-persist", str(keep))
    gw = start_gateway(pty_pair.gateway, *options)
    c = client(gw)
    # the configuration zone: "mbgw" (0x8000-), then NULs, two characters a register
    assert c.ask(247, read_holding(0x8000, 3)) == bytes.fromhex("03 06 6d62 6777 0000")
    assert c.ask(247, bytes.fromhex("10 0800 0002 04 1234 5678")) == \
        bytes.fromhex("10 0800 0002")
    result = mbgw("table", "write", "0x1000", "0xbeef", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert c.ask(253, read_holding(0x1000, 1)) == bytes.fromhex("03 02 beef")
    result = mbgw("table", "read", "0x0800", "2", "--json", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["values"] == [0x1234, 0x5678]
    table = status(gw)["table"]
    assert table["requests"]["16"] == {"answered": 1, "exception": 0, "broadcast": 0}
    assert table["requests"]["3"]["answered"] == 2
    assert gw.stop() == 0
    gw = start_gateway(pty_pair.gateway, *options)
    assert client(gw).ask(247, read_holding(0x0800, 2)) == bytes.fromhex("03 04 1234 5678")
    assert client(gw).ask(247, read_holding(0x1000, 1)) == bytes.fromhex("03 02 beef")


@pytest.mark.usefixtures("state_directory")
def test_status_shows_while_the_table_file_cannot_be_written(tmp_path, pty_pair, start_peer,
                                                             start_gateway, client):
    """The file's directory is missing (as /var/lib/mbgw was before the units had a state
    directory): the daemon runs on, `mbgw status` says persistence is failing and why, and
    once the directory is there the next save clears it."""
    start_peer("pymodbus_slave.py", pty_pair.device, str(LINE_UNIT), "--silent-unknown")
    directory = tmp_path / "state"
    keep = directory / "table.bin"
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--table",
                       "--table-persist", str(keep), "--table-persist-interval", "1")
    assert client(gw).ask(247, bytes.fromhex("06 0800 0007")) == bytes.fromhex("06 0800 0007")
    failing = wait_for(gw, lambda s: "failing" in s["table"]["persist"], "persist failing")
    assert failing["table"]["persist"]["failing"] == \
        f"cannot write {keep}: No such file or directory"
    assert failing["table"]["persist"]["saves"] == 0
    result = mbgw("status", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert "  persist FAILING since " in result.stdout
    assert f": cannot write {keep}: No such file or directory (changes since the last save " \
        "are not kept)" in result.stdout
    directory.mkdir()
    wait_for(gw, lambda s: s["table"]["persist"]["saves"] == 1, "a save")
    assert "failing" not in status(gw)["table"]["persist"]
    assert "FAILING" not in mbgw("status", "--control", gw.control).stdout
    assert gw.stop() == 0
    assert keep.exists()


def test_without_the_table_there_is_no_table_section_and_no_table_command(pty_pair,
                                                                         start_gateway):
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200")
    assert "table" not in status(gw)
    result = mbgw("table", "read", "0", "--control", gw.control)
    assert result.returncode != 0 and "exchange table is off" in result.stderr, result.stderr


def test_the_location_is_in_status_and_the_zone_and_a_reload_changes_it(
        tmp_path, pty_pair, start_peer, start_gateway, client):
    """The guide's set location: shown by mbgw status, read at 0x8044 by a Modbus client."""
    start_peer("pymodbus_slave.py", pty_pair.device, str(LINE_UNIT), "--silent-unknown")
    path = tmp_path / "mbgw.toml"
    for words in (("serial", "baudrate", "19200"), ("table", "enabled", "on"),
                  ("general", "location", "Pump", "house", "3")):
        config_set(path, *words)
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    c = client(gw)
    assert c.ask(247, read_holding(0x8044, 7)) == \
        bytes.fromhex("03 0e") + b"Pump house 3\0\0"
    assert status(gw)["location"] == "Pump house 3"
    shown = mbgw("status", "--control", gw.control)
    assert "location   Pump house 3\n" in shown.stdout, shown.stdout
    config_set(path, "general", "location", "Hall", "B")
    reload(gw, "configuration reloaded: location changed")
    assert c.ask(247, read_holding(0x8044, 3)) == bytes.fromhex("03 06") + b"Hall B"
    assert status(gw)["location"] == "Hall B"
