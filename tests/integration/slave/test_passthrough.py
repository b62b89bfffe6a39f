"""Slave mode passes requests and replies through unchanged, against peers that are not ours:
pymodbus 3.16.1's RTU server on a socat pty behind the gateway, pymodbus's TCP client, Debian's
mbpoll and raw sockets in front of it.  Where pymodbus cannot serve a request (FC 08 with more
than 2 data bytes, codes it does not know), the test itself is the serial slave on the pty.

Byte-exact expectations are built here from the Modbus specification and the peer's known
contents (tests/peers/pymodbus_slave.py: holding register n holds 100 + n, input register n
holds 1000 + n, coils and discrete inputs alternate 1, 0; IDENTITY), never from mbgw's code.
"""
import os
import selectors
import socket
import struct
import subprocess
import time

import pytest
from pymodbus.client import ModbusTcpClient

from tests.harness import factory, read_pty
from tests.modbus import crc16, recv_adu
from tests.modbus import mbap as adu
from tests.peers.pymodbus_slave import IDENTITY

pytestmark = pytest.mark.integration

REPLY_TIMEOUT_S = 3.0
NO_REPLY_S = 0.5          # how long "no reply" is awaited


# ---- raw Modbus TCP, written from the TCP guide (3.1.3), independent of mbgw.line.native ----

def transact(sock: socket.socket, tid: int, unit: int, pdu: bytes) -> bytes:
    """Send one request and return the reply PDU, checking the MBAP header of the reply."""
    sock.sendall(adu(tid, unit, pdu))
    reply = recv_adu(sock)
    assert reply[:4] == struct.pack(">HH", tid, 0), reply.hex(" ")
    assert reply[6] == unit, reply.hex(" ")
    return reply[7:]


def registers(*values: int) -> bytes:
    return struct.pack(f">{len(values)}H", *values)


def read_registers_reply(function: int, first: int, count: int, base: int) -> bytes:
    return bytes((function, 2 * count)) + registers(*range(base + first, base + first + count))


def device_identification(read_code: int, object_ids) -> bytes:
    """Read Device Identification reply (application protocol 6.21): no more follows, next
    object 0; conformity 0x83 is what pymodbus declares (extended, stream + individual)."""
    objects = b"".join(bytes((oid, len(IDENTITY[oid]))) + IDENTITY[oid].encode()
                       for oid in object_ids)
    return bytes((0x2B, 0x0E, read_code, 0x83, 0x00, 0x00, len(object_ids))) + objects


@pytest.fixture
def gateway(pty_pair, start_peer, start_gateway):
    """pymodbus slaves 17 and 42 (with an identity) behind a gateway in slave mode."""
    start_peer("pymodbus_slave.py", pty_pair.device, "17", "42", "--identity")
    return start_gateway(pty_pair.gateway, "--baudrate", "19200")


@pytest.fixture
def connect(gateway):
    """connect() -> a TCP socket to the gateway; closed after the test."""
    yield from factory(lambda: socket.create_connection(("127.0.0.1", gateway.port),
                                                     timeout=REPLY_TIMEOUT_S), socket.socket.close)


@pytest.fixture
def client(gateway):
    c = ModbusTcpClient("127.0.0.1", port=gateway.port, timeout=REPLY_TIMEOUT_S, retries=0)
    assert c.connect()
    yield c
    c.close()


# ---- pymodbus's TCP client ----

def test_pymodbus_client_reads_every_table(client):
    rr = client.read_holding_registers(3, count=4, device_id=17)
    assert not rr.isError(), rr
    assert rr.registers == [103, 104, 105, 106]
    rr = client.read_input_registers(7, count=3, device_id=17)
    assert not rr.isError(), rr
    assert rr.registers == [1007, 1008, 1009]
    rr = client.read_coils(0, count=10, device_id=17)
    assert not rr.isError(), rr
    assert rr.bits[:10] == [True, False] * 5
    rr = client.read_discrete_inputs(1, count=5, device_id=17)
    assert not rr.isError(), rr
    assert rr.bits[:5] == [False, True, False, True, False]


def test_pymodbus_client_writes_and_reads_back(client):
    assert not client.write_register(20, 0xABCD, device_id=17).isError()
    assert client.read_holding_registers(20, count=1, device_id=17).registers == [0xABCD]

    assert not client.write_registers(30, [1, 2, 3], device_id=17).isError()
    assert client.read_holding_registers(29, count=5, device_id=17).registers == [129, 1, 2, 3, 133]

    assert not client.write_coil(1, True, device_id=17).isError()
    assert client.read_coils(0, count=3, device_id=17).bits[:3] == [True, True, True]

    assert not client.write_coils(10, [False, True, True, False], device_id=17).isError()
    assert client.read_coils(10, count=4, device_id=17).bits[:4] == [False, True, True, False]
    # the other slave on the line was not touched
    assert client.read_holding_registers(20, count=1, device_id=42).registers == [120]


def test_pymodbus_client_read_write_multiple_registers(client):
    # FC 0x17: the write happens before the read (application protocol 6.17)
    rr = client.readwrite_registers(read_address=40, read_count=4, write_address=41,
                                    values=[7, 8], device_id=17)
    assert not rr.isError(), rr
    assert rr.registers == [140, 7, 8, 143]


def test_pymodbus_client_mask_write_register(client):
    # FC 0x16: result = (current AND and_mask) OR (or_mask AND NOT and_mask):
    # register 50 holds 150 = 0x0096 -> 0x0090 | 0x0F05 = 0x0F95
    rr = client.mask_write_register(address=50, and_mask=0xF0F0, or_mask=0x0F05, device_id=17)
    assert not rr.isError(), rr
    assert (rr.address, rr.and_mask, rr.or_mask) == (50, 0xF0F0, 0x0F05)
    assert client.read_holding_registers(50, count=1, device_id=17).registers == [0x0F95]


def test_pymodbus_client_sees_the_slaves_exception(client):
    rr = client.read_holding_registers(99, count=2, device_id=17)   # 100 is beyond the store
    assert rr.isError()
    assert rr.exception_code == 0x02


# ---- byte-exact pass-through, raw sockets ----

SERVER_ID = "-".join(IDENTITY[i] for i in range(3)).encode()
FILE_RECORD = b"SERVER DUMMY RECORD."   # pymodbus 3.16.1 answers every FC 0x14 record with it

BYTE_EXACT = {
    # Exceptions from the slave pass unchanged, for a code libmodbus frames and for one it cannot.
    "fc03-exception-02": (bytes.fromhex("03 0063 0002"), bytes.fromhex("83 02")),
    "fc2b-exception-02": (bytes.fromhex("2b 0e 04 07"), bytes.fromhex("ab 02")),
    # FC 08 Diagnostics (6.8): 00 Return Query Data echoes the request; 01 Restart
    # Communications Option and 0A Clear Counters echo it too.  pymodbus frames an FC 08
    # request as exactly 8 bytes, so it can only echo 2 data bytes (see the raw slave below).
    "fc08-00-echo": (bytes.fromhex("08 0000 a55a"), bytes.fromhex("08 0000 a55a")),
    "fc08-01-restart": (bytes.fromhex("08 0001 ff00"), bytes.fromhex("08 0001 ff00")),
    "fc08-0a-clear": (bytes.fromhex("08 000a 0000"), bytes.fromhex("08 000a 0000")),
    # FC 0x2B / 0x0E Read Device Identification: basic, regular, extended (with the private
    # object 0x80: a 200-byte reply), one specific object.
    "fc2b-basic": (bytes.fromhex("2b 0e 01 00"), device_identification(0x01, [0, 1, 2])),
    "fc2b-regular": (bytes.fromhex("2b 0e 02 00"), device_identification(0x02, range(7))),
    "fc2b-extended": (bytes.fromhex("2b 0e 03 00"),
                      device_identification(0x03, [*range(7), 0x80])),
    "fc2b-specific": (bytes.fromhex("2b 0e 04 04"), device_identification(0x04, [4])),
    # FC 0x11 Report Server ID: pymodbus reports its basic identity objects joined by "-",
    # then run indicator ON.
    "fc11": (bytes.fromhex("11"), bytes((0x11, 1 + len(SERVER_ID))) + SERVER_ID + b"\xff"),
    # FC 0x14 Read File Record, two sub-requests (reference type 6); pymodbus returns its
    # fixed dummy record for each: byte count, then per record its length, 6, the data.
    # (pymodbus drops a request whose record length is odd.)
    "fc14": (bytes.fromhex("14 0e 06 0004 0001 0002 06 0003 0009 0004"),
             bytes((0x14, 2 * (2 + len(FILE_RECORD)))) +
             2 * (bytes((1 + len(FILE_RECORD), 6)) + FILE_RECORD)),
    # FC 0x15 Write File Record: the reply echoes the request.
    "fc15": (bytes.fromhex("15 0d 06 0004 0007 0003 1234 5678 9abc"),
             bytes.fromhex("15 0d 06 0004 0007 0003 1234 5678 9abc")),
    # FC 0x18 Read FIFO Queue: pymodbus's fixed queue 0, 1, 2, 3 (byte count 2 + 2 * 4).
    "fc18": (bytes.fromhex("18 0005"), bytes.fromhex("18 000a 0004 0000 0001 0002 0003")),
    # FC 07, 0x0B, 0x0C: pymodbus never counts, so status and counters are 0.
    "fc07": (bytes.fromhex("07"), bytes.fromhex("07 00")),
    "fc0b": (bytes.fromhex("0b"), bytes.fromhex("0b 0000 0000")),
    "fc0c": (bytes.fromhex("0c"), bytes.fromhex("0c 06 0000 0000 0000")),
    # Ordinary codes too: FC 0x17 and FC 0x16 byte for byte.
    "fc17": (bytes.fromhex("17 0010 0003 0060 0001 02 beef"),
             read_registers_reply(0x17, 16, 3, 100)),
    "fc16": (bytes.fromhex("16 0061 00ff 1200"), bytes.fromhex("16 0061 00ff 1200")),
}


@pytest.mark.parametrize("request_pdu, reply_pdu", BYTE_EXACT.values(), ids=BYTE_EXACT.keys())
def test_reply_passes_byte_exact(connect, request_pdu, reply_pdu):
    sock = connect()
    sock.sendall(adu(0x1234, 17, request_pdu))
    assert recv_adu(sock).hex(" ") == adu(0x1234, 17, reply_pdu).hex(" ")


def test_reply_carries_the_clients_transaction_and_unit_id(connect):
    sock = connect()
    for tid, unit in ((0xBEEF, 17), (0x0001, 42), (0xFFFF, 17), (0x0000, 42)):
        sock.sendall(adu(tid, unit, bytes.fromhex("04 0002 0002")))
        assert recv_adu(sock) == adu(tid, unit, read_registers_reply(0x04, 2, 2, 1000))


def test_pipelined_requests_are_answered_in_order(connect):
    sock = connect()
    requests = [(0x7000 + 3 * i, 7 * i, 1 + i % 3) for i in range(10)]   # tid, address, count
    sock.sendall(b"".join(adu(tid, 17, struct.pack(">BHH", 3, address, count))
                          for tid, address, count in requests))
    for tid, address, count in requests:
        assert recv_adu(sock) == adu(tid, 17, read_registers_reply(0x03, address, count, 100))


def test_a_client_pipelining_beyond_16_requests_gets_every_answer(connect):
    """With 16 or more of a client's requests in the gateway, it stops reading that
    connection, and reads on as answers go out: all are answered, in order."""
    sock = connect()

    def request(tid: int) -> bytes:
        return adu(tid, 17, struct.pack(">BHH", 3, tid, 1))

    sock.sendall(b"".join(request(tid) for tid in range(20)))
    assert recv_adu(sock) == adu(0, 17, read_registers_reply(0x03, 0, 1, 100))
    sock.sendall(b"".join(request(tid) for tid in range(20, 40)))    # while reading is paused
    for tid in range(1, 40):
        assert recv_adu(sock) == adu(tid, 17, read_registers_reply(0x03, tid, 1, 100))


def test_a_pipelining_client_does_not_starve_another(connect):
    a, b = connect(), connect()
    a_count = 15
    a.sendall(b"".join(adu(i, 17, struct.pack(">BHH", 3, i, 10)) for i in range(1, a_count + 1)))
    # Once A's first reply is back, all its requests are queued in the gateway; only then B asks.
    arrivals = []
    buffers = {a: b"", b: b""}
    sel = selectors.DefaultSelector()
    sel.register(a, selectors.EVENT_READ)
    sel.register(b, selectors.EVENT_READ)
    b_sent = False
    deadline = time.monotonic() + 10
    try:
        while len(arrivals) < a_count + 1:
            assert time.monotonic() < deadline, f"replies so far: {arrivals}"
            for key, _ in sel.select(0.5):
                chunk = key.fileobj.recv(4096)
                assert chunk, "the gateway closed a connection"
                buffers[key.fileobj] += chunk
                buf = buffers[key.fileobj]
                while len(buf) >= 6 and len(buf) >= 6 + struct.unpack(">H", buf[4:6])[0]:
                    end = 6 + struct.unpack(">H", buf[4:6])[0]
                    frame, buf = buf[:end], buf[end:]
                    tid = struct.unpack(">H", frame[:2])[0]
                    name = "A" if key.fileobj is a else "B"
                    expected = read_registers_reply(0x03, tid, 10, 100) if name == "A" else \
                        read_registers_reply(0x04, 0, 2, 1000)
                    assert frame == adu(tid, 17, expected)
                    arrivals.append((name, tid))
                buffers[key.fileobj] = buf
            if arrivals and not b_sent:
                b.sendall(adu(0xB0B, 17, bytes.fromhex("04 0000 0002")))
                b_sent = True
    finally:
        sel.close()
    assert [tid for name, tid in arrivals if name == "A"] == list(range(1, a_count + 1))
    assert arrivals.index(("B", 0xB0B)) < arrivals.index(("A", a_count)), arrivals


@pytest.mark.parametrize("exception", ["--no-exception", "--exception"])
def test_broadcast_writes_every_slave_and_gets_no_reply(pty_pair, start_peer, start_gateway,
                                                        exception):
    start_peer("pymodbus_slave.py", pty_pair.device, "17", "42")
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", exception)
    with socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_TIMEOUT_S) as sock:
        sock.sendall(adu(0x0B0D, 0, bytes.fromhex("06 003c 0bad")))
        sock.settimeout(NO_REPLY_S)
        with pytest.raises(socket.timeout):
            sock.recv(1024)
        sock.settimeout(REPLY_TIMEOUT_S)
        assert transact(sock, 0x0001, 17, bytes.fromhex("03 003c 0001")) == bytes.fromhex(
            "03 02 0bad")
        assert transact(sock, 0x0002, 42, bytes.fromhex("03 003c 0001")) == bytes.fromhex(
            "03 02 0bad")


# ---- a raw serial slave for what pymodbus cannot frame ----


RAW_SLAVE = {
    # FC 08 sub-function 00 with 6 data bytes: the slave echoes them all.
    "fc08-00-long-echo": (bytes.fromhex("08 0000 0102 0304 0506"),
                          bytes.fromhex("08 0000 0102 0304 0506")),
    # FC 08 sub-function 0x0E Return Server Message Count.
    "fc08-0e": (bytes.fromhex("08 000e 0000"), bytes.fromhex("08 000e 002a")),
    # A user-defined code (65) whose reply is longer than its request.
    "fc41": (bytes.fromhex("41 99"), bytes.fromhex("41") + bytes(range(40))),
}


@pytest.mark.parametrize("request_pdu, reply_pdu", RAW_SLAVE.values(), ids=RAW_SLAVE.keys())
def test_request_and_reply_cross_the_line_byte_exact(pty_pair, start_gateway, request_pdu,
                                                     reply_pdu):
    """The test is the serial slave: it checks the RTU frame the gateway puts on the line and
    answers it; the TCP client must get that answer unchanged."""
    fd = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)
    try:
        gw = start_gateway(pty_pair.gateway, "--baudrate", "19200")
        with socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_TIMEOUT_S) as sock:
            sock.sendall(adu(0x4242, 9, request_pdu))
            frame = bytes((9,)) + request_pdu
            assert read_pty(fd, len(frame) + 2).hex(" ") == (frame + crc16(frame)).hex(" ")
            frame = bytes((9,)) + reply_pdu
            os.write(fd, frame + crc16(frame))
            assert recv_adu(sock).hex(" ") == adu(0x4242, 9, reply_pdu).hex(" ")
    finally:
        os.close(fd)


# ---- mbpoll (Debian), a libmodbus-based client ----

def run_mbpoll(port: int, options, values=()) -> str:
    out = subprocess.run(["mbpoll", "-m", "tcp", "-a", "17", "-p", str(port), "-0", "-1",
                          *options, "127.0.0.1", *values],
                         capture_output=True, text=True, timeout=10)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def polled(output: str) -> dict[int, str]:
    """mbpoll's '[ref]: \tvalue' lines."""
    values = {}
    for line in output.splitlines():
        if line.startswith("[") and "]:" in line:
            ref, value = line.split("]:", 1)
            values[int(ref[1:])] = value.strip()
    return values


def test_mbpoll_reads_every_table(gateway):
    assert polled(run_mbpoll(gateway.port, ["-t", "4", "-r", "5", "-c", "3"])) == {
        5: "105", 6: "106", 7: "107"}
    assert polled(run_mbpoll(gateway.port, ["-t", "3", "-r", "98", "-c", "2"])) == {
        98: "1098", 99: "1099"}
    assert polled(run_mbpoll(gateway.port, ["-t", "0", "-r", "0", "-c", "4"])) == {
        0: "1", 1: "0", 2: "1", 3: "0"}
    assert polled(run_mbpoll(gateway.port, ["-t", "1", "-r", "3", "-c", "2"])) == {
        3: "0", 4: "1"}


def test_mbpoll_writes(gateway):
    # two values: FC 0x10; one value: FC 06; a coil: FC 05
    assert "Written 2 references" in run_mbpoll(gateway.port, ["-t", "4", "-r", "70"],
                                                 ["4242", "4343"])
    assert "Written 1 references" in run_mbpoll(gateway.port, ["-t", "4", "-r", "75"], ["7"])
    assert "Written 1 references" in run_mbpoll(gateway.port, ["-t", "0", "-r", "4"], ["0"])
    assert polled(run_mbpoll(gateway.port, ["-t", "4", "-r", "70", "-c", "6"])) == {
        70: "4242", 71: "4343", 72: "172", 73: "173", 74: "174", 75: "7"}
    assert polled(run_mbpoll(gateway.port, ["-t", "0", "-r", "4", "-c", "3"])) == {
        4: "0", 5: "0", 6: "1"}
