"""Master mode's exchange table (issue 14): a serial master on a socat pty reads and writes the
table at `table-address` (mbgw answers as a serial slave, RTU or ASCII), TCP clients read and
write it on `table-port`, and every other address still goes to its Modbus TCP server.

The masters are pymodbus's serial clients, `mbpoll -m rtu`, and raw frames written by the test
where the bytes matter; the TCP clients are pymodbus, `mbpoll -m tcp` and raw sockets.  Every
expected frame is built here from the specs (tests/modbus.py: its own CRC; the LRC below), never
by mbgw's code.  "No answer on the line" is checked by order: a request that must be answered
follows the one that must not, and the first bytes back must be its answer.
"""
import json
import os
import re
import select
import signal
import socket
import struct
import subprocess
import time

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.framer import FramerType

from tests.harness import factory, free_port, idle_connections, read_pty
from tests.integration.master.test_master import (
    BAUD,
    REPLY_S,
    holding_reply,
    identity,
    read_holding,
)
from tests.modbus import mbap, recv_adu
from tests.modbus import rtu_frame as rtu
from tests.ops import mbgw, status, tracing, wait_for

pytestmark = pytest.mark.integration

TABLE = 10                         # the table's serial address in these tests
SERVER = "127.0.3.1"               # serves serial addresses 1..4 (units 1..4)
SILENT = "127.0.3.2"               # serial address 20: accepts, never answers
ROUTES = (f"1 4 1 0 {SERVER}", f"20 20 1 0 {SILENT}")
OUTPUTS = 0x0800                   # VPGate's zones
FREE = 0x1000
CONFIG = 0x8000


@pytest.fixture
def servers(servers_at):
    return servers_at(SERVER, silent=(SILENT,))


@pytest.fixture
def table_master(start_master, servers):
    """table_master(*options, routes=ROUTES) -> (gateway, table-port): `mbgw master` with the
    table at serial address TABLE and served on a free TCP port."""
    def start(*options: str, routes=ROUTES):
        port = free_port()
        slaveid = [a for line in routes for a in ("--slaveid", line)]
        gw = start_master("--mdbport", str(servers[0]), *slaveid, "--table",
                          "--table-address", str(TABLE), "--table-port", str(port), *options)
        return gw, port
    return start


@pytest.fixture
def tcp():
    """tcp(port, source=None) -> a connected raw socket to 127.0.0.1:port (from the loopback
    address source); closed after the test."""
    def connect(port: int, source: str | None = None) -> socket.socket:
        return socket.create_connection(("127.0.0.1", port), timeout=REPLY_S,
                                        source_address=(source, 0) if source else None)

    yield from factory(connect, socket.socket.close)


def pymodbus_tcp(port: int) -> ModbusTcpClient:
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=REPLY_S, retries=0)
    assert client.connect()
    return client


def ask_tcp(sock: socket.socket, tid: int, unit: int, pdu: bytes) -> bytes:
    """The reply PDU to one request, its MBAP header checked (same tid and unit, length)."""
    sock.sendall(mbap(tid, unit, pdu))
    reply = recv_adu(sock)
    tid_back, protocol, length, unit_back = struct.unpack(">HHHB", reply[:7])
    assert (tid_back, protocol, unit_back, length) == (tid, 0, unit, len(reply) - 6)
    return reply[7:]


def write_multiple(address: int, start: int, *values: int) -> bytes:
    return struct.pack(f">BBHHB{len(values)}H", address, 0x10, start, len(values),
                       2 * len(values), *values)


def write_multiple_reply(address: int, start: int, count: int) -> bytes:
    return struct.pack(">BBHH", address, 0x10, start, count)


def line_is_silent(fd: int) -> bool:
    return not select.select([fd], [], [], 0)[0]


def table_status(gw) -> dict:
    return status(gw)["table"]


def mbpoll(*args: str, values=()) -> str:
    out = subprocess.run(["mbpoll", *args, *map(str, values)], capture_output=True, text=True,
                         timeout=10)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def mbpoll_rtu(device: str, *options: str, values=()) -> str:
    """mbpoll as the serial master, holding registers, PDU (0-based) addresses, once."""
    return mbpoll("-m", "rtu", "-b", BAUD, "-P", "none", "-a", str(TABLE), "-0", "-1", "-o",
                  str(REPLY_S), "-t", "4", *options, device, values=values)


# ---- the table between TCP clients and the serial master ----

def test_a_setpoint_a_tcp_client_writes_is_read_by_the_serial_master(table_master, serial_client,
                                                                    pty_pair):
    _, port = table_master()
    tcp_client = pymodbus_tcp(port)
    master = serial_client()
    try:
        assert not tcp_client.write_registers(OUTPUTS, [1200, 1201, 1202], device_id=1).isError()
        rr = master.read_holding_registers(OUTPUTS, count=3, device_id=TABLE)
        assert rr.registers == [1200, 1201, 1202]
        # the reverse: the serial master writes the free zone, the TCP client reads it
        assert not master.write_registers(FREE + 5, [7, 8], device_id=TABLE).isError()
        assert tcp_client.read_holding_registers(FREE + 5, count=2,
                                                 device_id=1).registers == [7, 8]
        # FC 4 reads the same registers; bits are bits of registers 0x0000-0x0FFF, LSB first
        assert master.read_input_registers(OUTPUTS, count=1,
                                           device_id=TABLE).registers == [1200]
        bit = OUTPUTS * 16 + 4       # 1200 = 0x04B0: bit 4 is 1, bit 0 is 0
        assert master.read_coils(bit, count=1, device_id=TABLE).bits[0] is True
        assert master.read_coils(OUTPUTS * 16, count=1, device_id=TABLE).bits[0] is False
    finally:
        tcp_client.close()
        master.close()
    # libmodbus's masters, serial and TCP
    mbpoll_rtu(pty_pair.device, "-r", str(FREE + 9), values=[4242])
    out = mbpoll("-m", "tcp", "-p", str(port), "-a", "1", "-0", "-1", "-o", str(REPLY_S),
                 "-t", "4", "-r", str(FREE + 9), "-c", "1", "127.0.0.1")
    assert f"[{FREE + 9}]: \t4242" in out


def test_the_table_address_answers_beside_the_routed_addresses(table_master, line, tcp):
    gw, port = table_master()
    sock = tcp(port)
    assert ask_tcp(sock, 1, 1, bytes.fromhex("10 1000 0002 04 1234 abcd")) == \
        bytes.fromhex("10 1000 0002")
    # the wire, byte-exact: routed address 2, then the table, then address 3
    os.write(line, rtu(read_holding(2)))
    expected = rtu(holding_reply(2, *identity(SERVER, 2)))
    assert read_pty(line, len(expected)) == expected
    os.write(line, rtu(read_holding(TABLE, FREE, 2)))
    expected = rtu(bytes.fromhex("0a 03 04 1234 abcd"))
    assert read_pty(line, len(expected)) == expected
    os.write(line, rtu(bytes.fromhex("0a 06 1001 beef")))        # FC 6 echoes
    expected = rtu(bytes.fromhex("0a 06 1001 beef"))
    assert read_pty(line, len(expected)) == expected
    os.write(line, rtu(write_multiple(TABLE, OUTPUTS, 1, 2, 3)))
    expected = rtu(write_multiple_reply(TABLE, OUTPUTS, 3))
    assert read_pty(line, len(expected)) == expected
    os.write(line, rtu(read_holding(3)))
    expected = rtu(holding_reply(3, *identity(SERVER, 3)))
    assert read_pty(line, len(expected)) == expected
    assert ask_tcp(sock, 2, 1, bytes.fromhex("03 1000 0002")) == bytes.fromhex("03 04 1234 beef")
    assert ask_tcp(sock, 3, 1, bytes.fromhex("03 0800 0003")) == \
        bytes.fromhex("03 06 0001 0002 0003")
    serial = table_status(gw)["serial"]
    assert (serial["requests"], serial["crc_errors"], serial["length_errors"],
            serial["send_failures"]) == (3, 0, 0, 0)


def test_a_broadcast_writes_the_table_and_gets_no_answer(table_master, line, tcp):
    gw, port = table_master()
    os.write(line, rtu(write_multiple(0, FREE + 100, 0x0102, 0x0304)))
    # silence: the next request's answer is the first thing on the line
    os.write(line, rtu(read_holding(TABLE, FREE + 100, 2)))
    expected = rtu(bytes.fromhex("0a 03 04 0102 0304"))
    assert read_pty(line, len(expected)) == expected
    assert ask_tcp(tcp(port), 9, 1, bytes.fromhex("03 1064 0002")) == \
        bytes.fromhex("03 04 0102 0304")
    table = table_status(gw)
    assert table["serial"]["requests"] == 1
    assert table["requests"]["16"] == {"answered": 0, "exception": 0, "broadcast": 1}


def test_a_bad_crc_to_the_table_address_is_counted_and_not_answered(table_master, line):
    gw, _ = table_master()
    bad = rtu(read_holding(TABLE, FREE, 1))
    bad = bad[:-1] + bytes((bad[-1] ^ 0xFF,))
    os.write(line, bad)
    # a frame cut short (3 bytes) for the table: an invalid length
    wait_for(gw, lambda s: s["table"]["serial"]["crc_errors"] == 1, "counted the bad CRC")
    os.write(line, bytes((TABLE, 0x03, 0x10)))
    wait_for(gw, lambda s: s["table"]["serial"]["length_errors"] == 1, "counted the short frame")
    os.write(line, rtu(read_holding(TABLE, FREE, 1)))
    expected = rtu(bytes.fromhex("0a 03 02 0000"))
    assert read_pty(line, len(expected)) == expected
    serial = table_status(gw)["serial"]
    assert (serial["requests"], serial["crc_errors"], serial["length_errors"]) == (1, 1, 1)


def test_a_byte_count_that_does_not_match_is_a_length_error_answered_0x03(table_master, line):
    gw, _ = table_master()
    # FC 16 for 2 registers with a byte count of 2 (and 2 bytes): ended by silence, valid CRC
    os.write(line, rtu(bytes.fromhex("0a 10 1000 0002 02 0001")))
    expected = rtu(bytes.fromhex("0a 90 03"))
    assert read_pty(line, len(expected)) == expected
    assert table_status(gw)["serial"]["length_errors"] == 1


# ---- ASCII ----

def lrc_frame(adu: bytes) -> bytes:
    """Modbus ASCII (Serial Line V1.02 2.5.2): ':' the ADU and its LRC in hex, CR LF."""
    lrc = -sum(adu) & 0xFF
    return b":" + (adu + bytes((lrc,))).hex().upper().encode() + b"\r\n"


def test_an_ascii_master_reads_and_writes_the_table(table_master, serial_client, line):
    gw, port = table_master("--protocol", "ascii")
    master = serial_client(FramerType.ASCII)
    assert not master.write_register(OUTPUTS + 1, 0x55AA, device_id=TABLE).isError()
    assert master.read_holding_registers(OUTPUTS, count=2,
                                         device_id=TABLE).registers == [0, 0x55AA]
    rr = master.read_holding_registers(0, count=3, device_id=2)        # routed, as before
    assert rr.registers == identity(SERVER, 2)
    master.close()
    os.write(line, lrc_frame(read_holding(TABLE, OUTPUTS + 1, 1)))
    expected = lrc_frame(bytes.fromhex("0a 03 02 55aa"))
    assert read_pty(line, len(expected)) == expected
    bad = lrc_frame(read_holding(TABLE, OUTPUTS, 1))
    bad = bad[:-4] + (b"00" if bad[-4:-2] != b"00" else b"01") + b"\r\n"    # a wrong LRC
    os.write(line, bad + lrc_frame(bytes.fromhex("0a 06 0800 0001")))
    expected = lrc_frame(bytes.fromhex("0a 06 0800 0001"))
    assert read_pty(line, len(expected)) == expected
    serial = table_status(gw)["serial"]
    assert (serial["requests"], serial["crc_errors"]) == (4, 1)


# ---- a pure Modbus RTU server of local data ----

def test_with_an_empty_slaveid_table_mbgw_is_a_modbus_rtu_server_of_local_data(
        table_master, pty_pair, line, tcp):
    gw, port = table_master(routes=())
    assert "mbgw is a Modbus RTU server of the exchange table only, at address 10" in gw.log()
    assert "every request on the line is ignored" not in gw.log()
    assert "slaveid    empty: only the table's address 10 is answered" in \
        mbgw("status", "--control", gw.control).stdout
    ask_tcp(tcp(port), 1, 1, bytes.fromhex("10 0000 0002 04 0011 0022"))
    assert "[0]: \t17\n[1]: \t34" in mbpoll_rtu(pty_pair.device, "-r", "0", "-c", "2")
    # any other address is another slave's
    os.write(line, rtu(read_holding(2)) + rtu(read_holding(TABLE, 1, 1)))
    expected = rtu(bytes.fromhex("0a 03 02 0022"))
    assert read_pty(line, len(expected)) == expected


# ---- exceptions reach the serial master ----

def test_exceptions_reach_the_serial_master(table_master, serial_client, line):
    table_master("--table-functions", "1,3,4,16")
    cases = [
        (write_multiple(TABLE, CONFIG, 1), bytes.fromhex("0a 90 02")),   # the config zone
        (bytes.fromhex("0a 06 1000 0001"), bytes.fromhex("0a 86 01")),   # FC 6 disabled
        (bytes.fromhex("0a 18 04 de"), bytes.fromhex("0a 98 01")),       # not a table function
        (read_holding(TABLE, 0xFFFF, 2), bytes.fromhex("0a 83 02")),     # beyond 65,535
        (read_holding(TABLE, 0, 126), bytes.fromhex("0a 83 03")),        # over 125 registers
        (read_holding(TABLE, CONFIG, 2), bytes.fromhex("0a 03 04 6d62 6777")),   # "mbgw"
    ]
    for request, answer in cases:
        os.write(line, rtu(request))
        expected = rtu(answer)
        assert read_pty(line, len(expected)).hex(" ") == expected.hex(" "), request.hex(" ")
    master = serial_client()
    rr = master.write_register(FREE, 1, device_id=TABLE)
    assert rr.isError() and rr.exception_code == 0x01
    rr = master.write_registers(CONFIG + 0x100, [1], device_id=TABLE)
    assert rr.isError() and rr.exception_code == 0x02
    master.close()


# ---- the TCP side never waits for the line ----

def test_table_port_answers_while_a_serial_request_waits_for_a_silent_server(table_master,
                                                                          line, tcp):
    gw, port = table_master("--tcpto", "2000", "--exception")
    sock = tcp(port)
    os.write(line, rtu(read_holding(20)))
    wait_for(gw, lambda s: s["counters"]["requests"] == 1, "took the request for 20")
    for tid in range(1, 21):
        assert ask_tcp(sock, tid, 1, bytes.fromhex("03 1000 0001")) == bytes.fromhex("03 02 0000")
    assert line_is_silent(line)          # the serial request is still waiting for its server
    expected = rtu(bytes.fromhex("14 83 0b"))
    assert read_pty(line, len(expected)) == expected


def test_the_tcp_server_frames_pipelined_requests_broadcasts_and_bad_headers(table_master, tcp):
    gw, port = table_master()
    sock = tcp(port)
    requests = [mbap(1, 1, bytes.fromhex("06 1000 0007")),
                mbap(2, 0, bytes.fromhex("06 1001 0008")),     # unit 0: a broadcast, no reply
                mbap(3, 7, bytes.fromhex("03 1000 0002"))]
    whole = b"".join(requests)
    sock.sendall(whole[:5])
    sock.sendall(whole[5:])
    assert recv_adu(sock) == mbap(1, 1, bytes.fromhex("06 1000 0007"))
    assert recv_adu(sock) == mbap(3, 7, bytes.fromhex("03 04 0007 0008"))
    other = tcp(port)
    other.sendall(struct.pack(">HHHB", 1, 5, 6, 1) + bytes.fromhex("03 0000 0001"))
    assert other.recv(16) == b""               # protocol id 5: that connection is closed
    assert ask_tcp(sock, 4, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    tcp_figures = table_status(gw)["tcp"]
    assert (tcp_figures["connections_bad_header"], tcp_figures["connections"]) == (1, 1)


def test_fc7_tells_a_device_that_is_down(table_master, line, tcp):
    gw, port = table_master("--tcpto", "100", "--down-after", "1")
    os.write(line, rtu(read_holding(20)))
    wait_for(gw, lambda s: any(d["address"] == 20 and d["health"] == "down"
                               for d in s["devices"]), "took 20 down")
    assert ask_tcp(tcp(port), 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 04")
    os.write(line, rtu(bytes.fromhex("0a 07")))
    expected = rtu(bytes.fromhex("0a 07 04"))
    assert read_pty(line, len(expected)) == expected


def test_more_than_32_polling_tcp_clients_are_refused(table_master, tcp):
    gw, port = table_master()
    clients = [tcp(port, f"127.0.0.{1 + n // 8}") for n in range(32)]     # 8 an address
    for tid, sock in enumerate(clients):
        assert ask_tcp(sock, tid, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    extra = tcp(port, "127.0.0.9")
    assert extra.recv(16) == b""
    assert table_status(gw)["tcp"]["connections_refused_limit"] == 1
    assert "table client 127.0.0.9" in gw.log() and "refused" in gw.log()


def test_one_address_has_a_share_and_silent_clients_make_room(table_master, tcp):
    gw, port = table_master()
    silent = [tcp(port) for _ in range(8)]          # the address's share, and none polls
    newcomer = tcp(port)                            # takes the place of the oldest silent one
    assert ask_tcp(newcomer, 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    assert silent[0].recv(16) == b""
    for tid, sock in enumerate(silent[1:]):
        assert ask_tcp(sock, tid, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    extra = tcp(port)                               # every one polls now: refused
    assert extra.recv(16) == b""
    figures = table_status(gw)["tcp"]
    assert (figures["connections_evicted"], figures["connections_refused_limit"]) == (1, 1)
    other = tcp(port, "127.0.0.2")                  # another address has room
    assert ask_tcp(other, 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")


@pytest.mark.usefixtures("many_fds")
def test_idle_connections_to_the_table_port_cost_nothing_and_a_poller_is_served(
        table_master, tcp):
    gw, port = table_master()
    poller = tcp(port, "127.0.0.2")
    assert ask_tcp(poller, 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    pid = gw.proc.pid
    fds_before, cpu_before = len(os.listdir(f"/proc/{pid}/fd")), cpu_s(pid)
    log_before = len(gw.log().splitlines())
    idle = idle_connections(port, 50)   # never a byte: each replaces the oldest silent one
    try:
        deadline = time.monotonic() + 3.0
        tid = 2
        while time.monotonic() < deadline:
            assert ask_tcp(poller, tid, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
            tid += 1
            time.sleep(0.05)
        assert len(os.listdir(f"/proc/{pid}/fd")) <= fds_before + 8    # the address's share
        assert cpu_s(pid) - cpu_before < 1.5                             # of 3 s: no spinning
        assert len(gw.log().splitlines()) - log_before <= 2
    finally:
        for sock in idle:
            sock.close()


def cpu_s(pid: int) -> float:
    """The process's user and system time so far (/proc/PID/stat utime + stime)."""
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_a_table_request_not_whole_within_request_timeout_closes_its_connection(
        table_master, tcp):
    gw, port = table_master("--request-timeout", "300")
    poller, dribbler = tcp(port), tcp(port)
    assert ask_tcp(poller, 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    dribbler.sendall(bytes.fromhex("0001 0000 0002"))       # a header, and no more
    dribbler.settimeout(3.0)
    assert dribbler.recv(16) == b""
    assert table_status(gw)["tcp"]["connections_timed_out"] == 1
    assert ask_tcp(poller, 2, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")


# ---- the operator, persistence, reload ----

def test_the_operator_reads_and_writes_the_table_the_serial_master_sees(table_master, line, tcp):
    gw, port = table_master()
    done = mbgw("table", "write", "--control", gw.control, hex(FREE + 1), "0x1234", "5")
    assert done.returncode == 0, done.stderr
    os.write(line, rtu(read_holding(TABLE, FREE + 1, 2)))
    expected = rtu(bytes.fromhex("0a 03 04 1234 0005"))
    assert read_pty(line, len(expected)) == expected
    ask_tcp(tcp(port), 1, 1, bytes.fromhex("06 0800 002a"))
    read = mbgw("table", "read", "--control", gw.control, "--json", hex(OUTPUTS))
    assert read.returncode == 0, read.stderr
    assert json.loads(read.stdout)["values"] == [42]
    shown = mbgw("status", "--control", gw.control)
    assert "serial slave: 1 requests, 0 invalid CRC, 0 invalid length, 0 failed sends" in \
        shown.stdout
    assert "TCP server: 1 of 32 clients, 1 accepted" in shown.stdout


@pytest.mark.usefixtures("state_directory")
def test_outputs_and_free_zone_survive_a_restart(start_master, servers, tmp_path, line, tcp):
    path = tmp_path / "table.bin"
    port = free_port()
    options = ("--mdbport", str(servers[0]), "--table", "--table-address", str(TABLE),
               "--table-port", str(port), "--table-persist", str(path))
    gw = start_master(*options)
    sock = tcp(port)
    ask_tcp(sock, 1, 1, bytes.fromhex("10 0800 0002 04 0102 0304"))
    ask_tcp(sock, 2, 1, bytes.fromhex("06 7fff beef"))
    ask_tcp(sock, 3, 1, bytes.fromhex("06 0010 0001"))        # an input: not kept
    sock.close()
    saved = wait_for(gw, lambda s: s["table"]["persist"]["saves"] == 1, "the first save")
    assert saved["table"]["persist"]["path"] == str(path)
    assert "failing" not in saved["table"]["persist"]
    assert gw.stop() == 0
    assert path.exists()
    start_master(*options)
    os.write(line, rtu(read_holding(TABLE, OUTPUTS, 2)))
    expected = rtu(bytes.fromhex("0a 03 04 0102 0304"))
    assert read_pty(line, len(expected)) == expected
    assert ask_tcp(tcp(port), 4, 1, bytes.fromhex("03 7fff 0001")) == bytes.fromhex("03 02 beef")
    assert ask_tcp(tcp(port), 5, 1, bytes.fromhex("03 0010 0001")) == bytes.fromhex("03 02 0000")


def test_a_reload_moves_the_table_port_and_changes_the_functions(start_master, servers, tmp_path,
                                                                line, tcp):
    old_port, new_port = free_port(), free_port()
    config = tmp_path / "mbgw.toml"

    def write_config(port: int, functions: str) -> None:
        config.write_text(f'[serial]\nmode = "master"\nbaudrate = {BAUD}\n\n'
                          f'[net]\nmdbport = {servers[0]}\n\n[table]\nenabled = true\n'
                          f'address = {TABLE}\nport = {port}\nfunctions = "{functions}"\n')
    write_config(old_port, "3,6,16")
    gw = start_master("--config", str(config))
    assert ask_tcp(tcp(old_port), 1, 1, bytes.fromhex("06 1000 0001")) == \
        bytes.fromhex("06 1000 0001")
    write_config(new_port, "3,16")
    gw.proc.send_signal(signal.SIGHUP)
    wait_for(gw, lambda s: s["table"]["tcp"]["port"] == new_port, "moved to the new port")
    assert ask_tcp(tcp(new_port), 2, 1, bytes.fromhex("06 1000 0002")) == bytes.fromhex("86 01")
    os.write(line, rtu(read_holding(TABLE, FREE, 1)))
    expected = rtu(bytes.fromhex("0a 03 02 0001"))
    assert read_pty(line, len(expected)) == expected


def test_table_transactions_are_traced_with_outcome_table(table_master, line, tmp_path):
    gw, _ = table_master()
    with tracing(gw, tmp_path / "trace.pcap", count=3) as (trace, _):
        os.write(line, rtu(bytes.fromhex("0a 06 1000 0009")))
        expected = rtu(bytes.fromhex("0a 06 1000 0009"))
        assert read_pty(line, len(expected)) == expected
        os.write(line, rtu(bytes.fromhex("00 06 1000 000a")))     # a broadcast: its event
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    rows = [re.sub(r" [\d.]+ ms$", "", row).split()[1:] for row in out.decode().splitlines()]
    assert rows[:3] == [["request", "10", "table", "-", "-", "0x06", "5"],
                        ["reply", "10", "table", "-", "-", "0x06", "5", "table"],
                        ["request", "0", "table", "-", "-", "0x06", "5"]]


INTERFRAME_MS = 300


def test_the_interframe_silence_delays_the_answer_to_the_serial_master(table_master, line):
    """VPGate's interframe silence, master mode: the table's answer and a routed one come no
    sooner than it after the request (a lower bound: load only makes it later)."""
    gw, _ = table_master("--interframe-silence", str(INTERFRAME_MS))
    for request, reply in ((read_holding(TABLE, CONFIG, 2), bytes.fromhex("0a 03 04 6d62 6777")),
                           (read_holding(2), holding_reply(2, *identity(SERVER, 2)))):
        os.write(line, rtu(request))
        written = time.monotonic()
        assert read_pty(line, len(rtu(reply))) == rtu(reply)
        assert time.monotonic() - written >= INTERFRAME_MS / 1000


def test_the_master_moving_on_during_the_interframe_silence_abandons_the_answer(table_master,
                                                                                 line):
    gw, _ = table_master("--interframe-silence", "2000")
    os.write(line, rtu(read_holding(TABLE, CONFIG, 2)))
    wait_for(gw, lambda s: s["table"]["serial"]["requests"] == 1, "the first request taken")
    os.write(line, rtu(read_holding(TABLE, CONFIG, 1)))     # the master moved on
    expected = rtu(bytes.fromhex("0a 03 02 6d62"))
    assert read_pty(line, len(expected), timeout=REPLY_S + 2) == expected   # the second's only
    assert status(gw)["counters"]["abandoned"] == 1


def test_the_serial_slave_and_the_tcp_clients_have_function_lists_of_their_own(table_master,
                                                                              line, tcp):
    """VPGate 3.7: the serial master may write (6) what the TCP clients may only read (3, 4);
    each side's refusal is 0x01 and changes nothing."""
    gw, port = table_master("--table-functions", "3,4", "--table-serial-functions", "3,6")
    sock = tcp(port)
    os.write(line, rtu(bytes.fromhex("0a 06 1000 beef")))
    expected = rtu(bytes.fromhex("0a 06 1000 beef"))
    assert read_pty(line, len(expected)) == expected
    assert ask_tcp(sock, 1, 1, bytes.fromhex("06 1000 0001")) == bytes.fromhex("86 01")
    assert ask_tcp(sock, 2, 1, bytes.fromhex("03 1000 0001")) == bytes.fromhex("03 02 beef")
    os.write(line, rtu(bytes.fromhex("0a 04 1000 0001")))
    expected = rtu(bytes.fromhex("0a 84 01"))
    assert read_pty(line, len(expected)) == expected
    os.write(line, rtu(read_holding(TABLE, FREE, 1)))
    expected = rtu(bytes.fromhex("0a 03 02 beef"))
    assert read_pty(line, len(expected)) == expected
    assert table_status(gw)["serial"]["requests"] == 3


def test_the_table_servers_own_max_connections(table_master, tcp):
    """[table] max-connections (not net.max-connections, the servers'): with 2, a third
    polling client is refused, naming the key (one address may fill a cap this small)."""
    gw, port = table_master("--table-max-connections", "2")
    clients = [tcp(port) for _ in range(2)]
    for tid, sock in enumerate(clients):
        assert ask_tcp(sock, tid, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    extra = tcp(port, "127.0.0.2")
    assert extra.recv(16) == b""
    tcp_figures = table_status(gw)["tcp"]
    assert (tcp_figures["max_connections"], tcp_figures["connections_refused_limit"]) == (2, 1)
    assert "2 table clients are connected, the most there may be (table.max-connections)" \
        in gw.log()
    assert "exchange table served on" in gw.log() and "(at most 2 clients)" in gw.log()


def _write_master_config(path, servers, port: int, net: str) -> None:
    path.write_text(f'[serial]\nmode = "master"\nbaudrate = {BAUD}\n\n'
                    f'[net]\nmdbport = {servers[0]}\n{net}\n[table]\nenabled = true\n'
                    f'address = {TABLE}\nport = {port}\n')


def test_authip_refuses_the_table_clients_and_a_reload_closes_those_it_drops(
        start_master, servers, tmp_path, tcp):
    """net.authip filters the table server's clients in master mode: one from elsewhere is
    closed before any byte; a reload that drops an address closes its open client."""
    port, config = free_port(), tmp_path / "mbgw.toml"
    _write_master_config(config, servers, port, 'authip = ["127.0.0.1"]\n')
    gw = start_master("--config", str(config))
    allowed = tcp(port)
    assert ask_tcp(allowed, 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    assert _closed(tcp(port, "127.0.0.2"))
    wait_for(gw, lambda s: s["table"]["tcp"]["connections_refused_authip"] == 1,
             "the refusal counted")
    _write_master_config(config, servers, port, 'authip = ["127.0.0.2"]\n')
    gw.proc.send_signal(signal.SIGHUP)
    assert _closed(allowed)          # the reload closed it
    assert "table client 127.0.0.1:" in gw.log() and "no longer allowed by authip" in gw.log()
    assert ask_tcp(tcp(port, "127.0.0.2"), 2, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")


def test_bind_serves_the_table_on_one_address_and_a_reload_moves_it(
        start_master, servers, tmp_path, tcp):
    """net.bind: the table server listens there only (127.0.0.1 is refused); a reload moves
    it, the open clients staying."""
    port, config = free_port(), tmp_path / "mbgw.toml"
    _write_master_config(config, servers, port, 'bind = "127.0.0.2"\n')
    gw = start_master("--config", str(config))
    with pytest.raises(ConnectionRefusedError):
        tcp(port)
    kept = socket.create_connection(("127.0.0.2", port), timeout=REPLY_S)
    with kept:
        assert ask_tcp(kept, 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
        _write_master_config(config, servers, port, 'bind = "127.0.0.1"\n')
        gw.proc.send_signal(signal.SIGHUP)
        wait_for(gw, lambda s: "table server: listening on 127.0.0.1:" in gw.log(),
                 "listening on the new address")
        assert ask_tcp(tcp(port), 2, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.2", port), timeout=REPLY_S)
        assert ask_tcp(kept, 3, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")


def test_the_table_clients_are_listed_and_closed_by_the_operator(table_master, tcp):
    """mbgw clients lists the table server's clients (slave mode's columns); clients close
    ID, IP:PORT and --all end their sockets, logged with the operator."""
    gw, port = table_master()
    first, second = tcp(port), tcp(port, "127.0.0.2")
    for tid, sock in enumerate((first, second)):
        assert ask_tcp(sock, tid, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    listed = wait_for(gw, lambda s: [c["requests"] for c in s["clients"]] == [1, 1],
                      "both clients listed")["clients"]
    peers = [c["peer"] for c in listed]
    assert peers == [_name(first.getsockname()), _name(second.getsockname())]
    text = mbgw("clients", "--control", gw.control).stdout
    assert text.startswith("table clients (2)") and peers[1] in text, text
    assert "table clients (2)" in mbgw("status", "--control", gw.control).stdout

    result = mbgw("clients", "close", str(listed[0]["id"]), "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert _closed(first)
    assert "table client %s closed by the operator" % peers[0] in gw.log()
    result = mbgw("clients", "close", peers[1], "--control", gw.control)
    assert result.returncode == 0 and f"({peers[1]}) closed" in result.stdout, result.stderr
    assert _closed(second)
    third = tcp(port)
    assert ask_tcp(third, 9, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
    result = mbgw("clients", "close", "--all", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert _closed(third)
    result = mbgw("clients", "close", "99", "--control", gw.control)
    assert result.returncode == 1 and "no client 99" in result.stderr


def _name(address) -> str:
    return f"{address[0]}:{address[1]}"


def _closed(sock: socket.socket) -> bool:
    try:
        return sock.recv(16) == b""
    except ConnectionResetError:
        return True


def test_a_bind_the_reload_cannot_listen_on_leaves_the_table_where_it_was(
        start_master, servers, tmp_path, tcp):
    port, config = free_port(), tmp_path / "mbgw.toml"
    _write_master_config(config, servers, port, 'bind = "127.0.0.1"\n')
    gw = start_master("--config", str(config))
    _write_master_config(config, servers, port, 'bind = "192.0.2.1"\n')   # not this machine's
    gw.proc.send_signal(signal.SIGHUP)
    wait_for(gw, lambda s: "not applied: bind: table-port" in gw.log(), "the refusal logged")
    assert f"the table is still served on 127.0.0.1:{port}" in gw.log()
    assert ask_tcp(tcp(port), 1, 1, bytes.fromhex("07")) == bytes.fromhex("07 00")
