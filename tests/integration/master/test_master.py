"""Master mode end to end: a serial master on one end of a socat pty pair, `mbgw master` on the
other, and pymodbus Modbus TCP servers (peers/pymodbus_tcp_servers.py) on loopback addresses.

The masters are mbpoll (RTU), pymodbus's serial client (RTU and ASCII), and raw frames written
by the test where it must control the bytes (another slave's reply, broadcasts).  "No answer
on the line" is checked by order wherever possible: the master sends a request that must be
answered right behind the one that must not, and the first frame to come back must be the
answer to the second.  Servers report each connection made and lost, so the upstream
connections are watched from the servers' side.
"""
import os
import select
import struct
import subprocess
import time

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.framer import FramerType

from mbgw.line import native
from tests import harness
from tests.harness import Gateway, Peer, factory, free_port, logged_counters, read_pty
from tests.modbus import rtu_frame as rtu

pytestmark = pytest.mark.integration

BAUD = "19200"
REPLY_S = 3.0                 # an answer that is due never takes this long
TCPTO_MS = 300
TCPTO_S = TCPTO_MS / 1000
NO_REPLY_S = TCPTO_S + 0.3    # long enough for an answer that would come at tcpto

# The guide's three examples, with 192.168 replaced by loopback 127.0: every server really
# exists (a server's registers 0..2 hold the third and fourth byte of its IP and the unit id).
GUIDE_LINES = ("1 8 1 0 127.0.0.30", "9 16 0 1 127.0.20.0", "17 24 31 1 127.0.50.0")
GUIDE_ROUTES = {
    1: ("127.0.0.30", 1), 4: ("127.0.0.30", 4), 8: ("127.0.0.30", 8),
    9: ("127.0.20.0", 0xFF), 12: ("127.0.20.3", 0xFF), 16: ("127.0.20.7", 0xFF),
    17: ("127.0.50.0", 31), 19: ("127.0.50.2", 33), 24: ("127.0.50.7", 38),
}
GUIDE_HOSTS = ("127.0.0.30", *(f"127.0.20.{i}" for i in range(8)),
               *(f"127.0.50.{i}" for i in range(8)))
EVICTION_HOSTS = ("127.0.1.1", "127.0.1.2", "127.0.1.3")
BROADCAST_HOSTS = ("127.0.4.1", "127.0.4.2", "127.0.4.3")
SILENT_HOST = "127.0.2.1"
ABSENT_HOST = "127.0.9.9"     # nobody listens there: connection refused
RESTART_HOST = "127.0.5.1"    # served by a peer of its own, restarted by a test
SLOW_MS = 1500                # peers answer a read of register 9 this late
LATE_TCPTO_MS = 1000          # the second request of the late-reply test is sent at this time
                              # and answered at SLOW_MS, so both sides have 500 ms of margin
OTHER = 50                    # a serial address outside every table here


# ---- reading the peers' and socat's output from the fd itself (harness._read_lines_until
# selects on the fd but reads through a buffered wrapper, and can miss lines) ----

class Lines:
    """The lines a subprocess prints, read straight from its pipe's fd."""

    def __init__(self, proc, stream) -> None:
        self.proc = proc
        self.fd = stream.fileno()
        self.lines: list[str] = []
        self._pending = b""

    def until(self, want, timeout: float = REPLY_S) -> list[str]:
        deadline = time.monotonic() + timeout
        while not want(self.lines):
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                raise TimeoutError(f"{self.proc.args[:3]}: no such line; said: {self.lines}")
            chunk = os.read(self.fd, 4096)
            if not chunk:
                raise RuntimeError(f"{self.proc.args[:3]} exited; said: {self.lines}")
            *done, self._pending = (self._pending + chunk).split(b"\n")
            self.lines += [line.decode(errors="replace") for line in done]
        return self.lines


def _read_lines_until(proc, stream, want, timeout: float) -> list[str]:
    lines = Lines(proc, stream)
    proc.lines = lines
    return lines.until(want, timeout)


@pytest.fixture(scope="module", autouse=True)
def _fd_line_reader():
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(harness, "_read_lines_until", _read_lines_until)
        yield


# ---- servers, line, gateway ----

@pytest.fixture(scope="module")
def servers():
    """Every remote server the module needs, in one process; yields (port, their Lines)."""
    port = free_port()
    peer = Peer("pymodbus_tcp_servers.py", str(port), *GUIDE_HOSTS, *EVICTION_HOSTS,
                *BROADCAST_HOSTS, SILENT_HOST, "--silent", SILENT_HOST,
                "--slow-ms", str(SLOW_MS))
    yield port, peer.proc.lines
    peer.stop()


@pytest.fixture
def gateway(tmp_path, pty_pair, servers):
    """gateway(*slaveid lines, options=[...]) -> a ready `mbgw master` on pty_pair.gateway
    that reaches `servers`."""
    def start(*lines: str, options=()) -> Gateway:
        port, _ = servers
        args = [a for line in lines for a in ("--slaveid", line)]
        return Gateway(tmp_path, pty_pair.gateway, "--baudrate", BAUD, "--mdbport", str(port),
                       *args, *options, mode="master", listen=False)

    yield from factory(start, Gateway.stop)


def counters(gw: Gateway) -> dict[str, int]:
    """Stop the gateway; the counters it logs at stop."""
    code = gw.stop()
    log = gw.log_path.read_text()
    assert code == 0, log
    return logged_counters(next(row for row in log.splitlines() if "stopped; counters:" in row))


# ---- frames ----

def read_holding(address: int, start: int = 0, count: int = 3) -> bytes:
    return struct.pack(">BBHH", address, 0x03, start, count)


def holding_reply(address: int, *values: int) -> bytes:
    return bytes((address, 0x03, 2 * len(values))) + struct.pack(f">{len(values)}H", *values)


def identity(host: str, unit: int) -> list[int]:
    """Registers 0..2 of a unit on a server: its IP's third and fourth bytes, the unit id."""
    c, d = (int(b) for b in host.split(".")[2:])
    return [c, d, unit]


def mbpoll(device: str, address: int, *options: str, values=()) -> str:
    """mbpoll on holding registers, PDU (0-based) addresses, once."""
    out = subprocess.run(["mbpoll", "-m", "rtu", "-b", BAUD, "-P", "none", "-a", str(address),
                          "-0", "-1", "-o", str(REPLY_S), "-t", "4", *options, device,
                          *map(str, values)], capture_output=True, text=True, timeout=10)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


# ---- the slaveid table ----

def test_the_guides_three_examples_reach_the_right_server_and_unit(gateway, serial_client,
                                                                    pty_pair):
    gw = gateway(*GUIDE_LINES)
    client = serial_client()
    for address, (host, unit) in GUIDE_ROUTES.items():
        rr = client.read_holding_registers(0, count=3, device_id=address)
        assert not rr.isError(), (address, rr)
        assert rr.registers == identity(host, unit), address
    client.close()
    # and mbpoll, a libmodbus master: slave 19 is 127.0.50.2, unit 33
    assert "[0]: \t50\n[1]: \t2\n[2]: \t33" in mbpoll(pty_pair.device, 19, "-r", "0", "-c", "3")
    log = gw.log()
    assert ("slaveid 1..8 -> 127.0.0.30 unit 1..8, 9..16 -> 127.0.20.0..127.0.20.7 unit 255, "
            "17..24 -> 127.0.50.0..127.0.50.7 unit 31..38") in log
    c = counters(gw)
    assert c["requests"] == c["replies"] == len(GUIDE_ROUTES) + 1
    # 12 servers for 5 connections
    assert c["connections_evicted"] > 0
    assert c["connections_opened"] - c["connections_evicted"] <= 5


def test_mbpoll_writes_reach_the_server(gateway, pty_pair, servers):
    gateway(*GUIDE_LINES)
    mbpoll(pty_pair.device, 12, "-r", "4", values=[4242])
    direct = ModbusTcpClient("127.0.20.3", port=servers[0], timeout=REPLY_S, retries=0)
    assert direct.connect()
    try:
        assert direct.read_holding_registers(4, count=1, device_id=0xFF).registers == [4242]
    finally:
        direct.close()
    assert "[4]: \t4242" in mbpoll(pty_pair.device, 12, "-r", "4", "-c", "1")


def test_addresses_outside_the_table_get_no_answer(gateway, line):
    gw = gateway(*GUIDE_LINES, options=["--exception"])
    for address in (OTHER, 25, 247, 255):
        os.write(line, rtu(read_holding(address)) + rtu(read_holding(1)))
        expected = rtu(holding_reply(1, *identity("127.0.0.30", 1)))
        assert read_pty(line, len(expected)).hex(" ") == expected.hex(" "), address
    c = counters(gw)
    assert (c["other_addresses"], c["requests"], c["replies"]) == (4, 4, 4)
    assert c["gateway_exceptions"] == 0


@pytest.mark.parametrize("other_request, other_reply", [
    (read_holding(OTHER), holding_reply(OTHER, 7, 8)),                    # longer reply
    (bytes.fromhex("32 10 0001 0002 04 000a 000b"), bytes.fromhex("32 10 0001 0002")),
    (read_holding(OTHER), bytes.fromhex("32 83 02")),                     # an exception
    (read_holding(OTHER, count=1), holding_reply(OTHER, 0x0103)),        # looks addressed to 1
], ids=["fc03", "fc10", "exception", "fc03-reply-holding-a-request"])
def test_another_slaves_reply_is_not_taken_for_a_request(gateway, line, other_request,
                                                         other_reply):
    """Another slave on the bus answers the master; both frames and the next request come in
    one burst (libmodbus would take the request for the other slave's reply)."""
    gw = gateway(*GUIDE_LINES)
    os.write(line, rtu(other_request) + rtu(other_reply) + rtu(read_holding(1)))
    expected = rtu(holding_reply(1, *identity("127.0.0.30", 1)))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["other_addresses"], c["requests"], c["crc_errors"], c["invalid_frames"]) == (
        2, 1, 0, 0)


@pytest.mark.parametrize("noise", ["ff", "00", "09 18 ff ff 01 02"],
                         ids=["glitch-ff", "glitch-00", "fifo-header"])
def test_noise_right_before_a_request_does_not_cost_it(gateway, line, noise):
    gw = gateway(*GUIDE_LINES)
    os.write(line, bytes.fromhex(noise) + rtu(read_holding(1)))
    expected = rtu(holding_reply(1, *identity("127.0.0.30", 1)))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["requests"], c["replies"], c["crc_errors"], c["invalid_frames"]) == (1, 1, 0, 0)


def test_a_remote_exception_passes_through(gateway, serial_client, line):
    gw = gateway(*GUIDE_LINES, options=["--exception"])
    client = serial_client()
    rr = client.read_holding_registers(10, count=1, device_id=17)     # past the server's table
    assert rr.isError() and rr.exception_code == 2
    client.close()
    os.write(line, rtu(read_holding(9, start=20, count=2)))
    expected = rtu(bytes.fromhex("09 83 02"))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["device_exceptions"], c["gateway_exceptions"]) == (2, 0)


# ---- failures: tcpto, unreachable, late replies ----

FAILING_LINES = ("1 1 1 0 127.0.0.30", f"2 2 1 0 {SILENT_HOST}", f"3 3 1 0 {ABSENT_HOST}")


def test_tcpto_with_exception_answers_0x0b(gateway, line):
    gw = gateway(*FAILING_LINES, options=["--tcpto", str(TCPTO_MS), "--exception"])
    started = time.monotonic()
    os.write(line, rtu(read_holding(2)))
    expected = rtu(bytes.fromhex("02 83 0b"))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    assert time.monotonic() - started >= TCPTO_S
    c = counters(gw)
    assert (c["timeouts"], c["gateway_exceptions"], c["replies"]) == (1, 1, 1)


def test_tcpto_without_exception_is_silence(gateway, line):
    gw = gateway(*FAILING_LINES, options=["--tcpto", str(TCPTO_MS)])
    os.write(line, rtu(read_holding(2)))
    assert read_pty(line, 1, NO_REPLY_S) == b""
    os.write(line, rtu(read_holding(1)))       # the gateway listens again
    expected = rtu(holding_reply(1, *identity("127.0.0.30", 1)))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["timeouts"], c["gateway_exceptions"], c["replies"]) == (1, 0, 1)


def test_an_answer_the_master_no_longer_waits_for_is_dropped(gateway, line):
    """The master gives up before tcpto and polls another slave: the 0x0B that tcpto brings
    for the first request must not go out, as the master would take it for the answer to the
    second one."""
    gw = gateway(*FAILING_LINES, options=["--tcpto", str(TCPTO_MS), "--exception"])
    os.write(line, rtu(read_holding(2)))
    os.write(line, rtu(read_holding(1)))
    expected = rtu(holding_reply(1, *identity("127.0.0.30", 1)))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["timeouts"], c["abandoned"], c["replies"]) == (1, 1, 1)


def test_an_unreachable_server_gets_0x0a_at_once_with_exception(gateway, line):
    gw = gateway(*FAILING_LINES, options=["--tcpto", "5000", "--exception"])
    started = time.monotonic()
    os.write(line, rtu(read_holding(3)))
    expected = rtu(bytes.fromhex("03 83 0a"))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    assert time.monotonic() - started < 2.0        # refused: no waiting for tcpto
    assert "server 127.0.9.9:" in gw.log() and "unreachable: Connection refused" in gw.log()
    c = counters(gw)
    assert (c["unreachable"], c["gateway_exceptions"]) == (1, 1)


def test_an_unreachable_server_without_exception_is_silence(gateway, line):
    gw = gateway(*FAILING_LINES, options=["--tcpto", "5000"])
    os.write(line, rtu(read_holding(3)) + rtu(read_holding(1)))
    expected = rtu(holding_reply(1, *identity("127.0.0.30", 1)))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["unreachable"], c["gateway_exceptions"], c["replies"]) == (1, 0, 1)


def test_a_late_reply_is_dropped_by_its_transaction_id(gateway, line):
    """The server answers register 9 after SLOW_MS, long after tcpto, on the connection the
    next request is then waiting on: only that request's own reply may reach the master."""
    gw = gateway(*FAILING_LINES, options=["--tcpto", str(LATE_TCPTO_MS), "--exception"])
    os.write(line, rtu(read_holding(1, start=9, count=1)))
    expected = rtu(bytes.fromhex("01 83 0b"))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    os.write(line, rtu(read_holding(1)))
    expected = rtu(holding_reply(1, *identity("127.0.0.30", 1)))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["timeouts"], c["late_replies"], c["replies"]) == (1, 1, 2)


# ---- connections ----

def test_the_least_recently_used_connection_makes_room(gateway, serial_client, servers):
    _, events = servers
    seen = len(events.lines)

    def mine(lines) -> list[str]:
        return [row for row in lines[seen:] if row.split()[-1] in EVICTION_HOSTS]

    gw = gateway(f"1 3 1 1 {EVICTION_HOSTS[0]}", options=["--max-connections", "2"])
    client = serial_client()
    for address in (1, 2, 1, 3):
        rr = client.read_holding_registers(0, count=3, device_id=address)
        assert rr.registers == identity(EVICTION_HOSTS[address - 1], address)
    events.until(lambda lines: {"CONNECT 127.0.1.3", "DISCONNECT 127.0.1.2"} <= set(mine(lines)))
    assert sorted(mine(events.lines)) == ["CONNECT 127.0.1.1", "CONNECT 127.0.1.2",
                                          "CONNECT 127.0.1.3", "DISCONNECT 127.0.1.2"]
    c = counters(gw)
    assert (c["connections_opened"], c["connections_evicted"]) == (3, 1)


def test_a_connection_the_server_closed_is_reopened_on_the_next_request(
        tmp_path, pty_pair, serial_client):
    port = free_port()
    peer = Peer("pymodbus_tcp_servers.py", str(port), RESTART_HOST)
    gw = Gateway(tmp_path, pty_pair.gateway, "--baudrate", BAUD, "--mdbport", str(port),
                 "--slaveid", f"1 1 1 0 {RESTART_HOST}", "--exception", mode="master",
                 listen=False)
    try:
        client = serial_client()
        assert client.read_holding_registers(0, count=3, device_id=1).registers == [5, 1, 1]
        peer.stop()                  # the server goes away; its connection is closed
        peer = Peer("pymodbus_tcp_servers.py", str(port), RESTART_HOST)
        rr = client.read_holding_registers(0, count=3, device_id=1)
        assert not rr.isError(), rr
        assert rr.registers == [5, 1, 1]
    finally:
        peer.stop()
        c = counters(gw)
    assert (c["connections_opened"], c["connections_lost"], c["replies"]) == (2, 1, 2)


# ---- broadcast ----

def test_a_broadcast_reaches_every_server_with_unit_0_and_gets_no_answer(gateway, line,
                                                                         servers):
    port, _ = servers
    gw = gateway(f"1 1 5 0 {BROADCAST_HOSTS[0]}", f"2 3 6 1 {BROADCAST_HOSTS[1]}",
                 options=["--exception"])
    value = 0x4B1D
    os.write(line, rtu(bytes.fromhex("00 06 0005") + struct.pack(">H", value)))
    # unit 0 writes every unit of a server: read back a unit the table never names
    for host in BROADCAST_HOSTS:
        direct = ModbusTcpClient(host, port=port, timeout=REPLY_S, retries=0)
        assert direct.connect()
        try:
            deadline = time.monotonic() + REPLY_S
            while direct.read_holding_registers(5, count=1, device_id=40).registers != [value]:
                assert time.monotonic() < deadline, f"{host} did not get the broadcast"
        finally:
            direct.close()
    os.write(line, rtu(read_holding(1)))
    expected = rtu(holding_reply(1, *identity(BROADCAST_HOSTS[0], 5)))
    assert read_pty(line, len(expected)).hex(" ") == expected.hex(" ")
    c = counters(gw)
    assert (c["broadcasts"], c["requests"], c["replies"], c["gateway_exceptions"]) == (1, 1, 1, 0)


# ---- ASCII ----

def ascii_frame(adu: bytes) -> bytes:
    return native.ascii_encode(adu)


def test_an_ascii_master(gateway, serial_client, line):
    gw = gateway(*GUIDE_LINES, options=["--protocol", "ascii", "--exception"])
    client = serial_client(FramerType.ASCII)
    for address in (4, 12, 19):
        rr = client.read_holding_registers(0, count=3, device_id=address)
        assert rr.registers == identity(*GUIDE_ROUTES[address]), address
    assert not client.write_register(6, 606, device_id=24).isError()
    assert client.read_holding_registers(6, count=1, device_id=24).registers == [606]
    rr = client.read_holding_registers(10, count=1, device_id=24)
    assert rr.isError() and rr.exception_code == 2
    client.close()
    # an address outside the table, and its slave's answer, then one of ours
    os.write(line, ascii_frame(read_holding(OTHER)) + ascii_frame(holding_reply(OTHER, 1, 2))
             + ascii_frame(read_holding(1)))
    expected = ascii_frame(holding_reply(1, *identity("127.0.0.30", 1)))
    assert read_pty(line, len(expected)) == expected
    c = counters(gw)
    assert (c["requests"], c["other_addresses"], c["device_exceptions"]) == (7, 2, 1)
