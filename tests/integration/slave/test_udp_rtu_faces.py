"""The Modbus TCP face's other listeners (issue 26): Modbus/UDP on `[net] udp-port` and RTU
over TCP on `[net] rtu-port`, with mdbport's routes, authip and firewall.  Peers: pymodbus's
RTU slave on the pty (tests/peers/pymodbus_slave.py, address 17, holding register i holds
100 + i, its record the wire) or the scripted one (fault_slave.py, address 3 answers late),
pymodbus's UDP client and RTU-framed TCP client, raw sockets."""
import re
import socket
import struct
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient, ModbusUdpClient
from pymodbus.framer import FramerType

from mbgw.line.native import rtu_adu
from tests.harness import free_port
from tests.integration.lines.test_lines_observed import TraceStream
from tests.integration.ops.test_reload import reload
from tests.modbus import mbap
from tests.ops import mbgw, metric_value, scraped, status
from tests.wait import until

pytestmark = pytest.mark.integration

REPLY_S = 3.0
SILENCE_S = 0.5             # a datagram that never comes: this long is the assertion
UNIT = 17


def read(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 3, address, count)


def write(address: int, value: int) -> bytes:
    return struct.pack(">BHH", 6, address, value)


def on_the_wire(record) -> list[str]:
    """The requests the serial slave received, as hex (address and PDU)."""
    if not record.exists():
        return []
    return [line.split(" ", 2)[2] for line in record.read_text().splitlines()
            if line.split(" ", 2)[1] == "rx"]


@pytest.fixture
def faces(tmp_path, pty_pair, start_peer, start_gateway):
    """faces(text, *options, peer=...) -> (gateway, udp-port, rtu-port, the slave's record):
    a slave-mode gateway with both faces on, text added to its file."""
    def start(text: str = "", *options: str, peer: str = "pymodbus_slave.py"):
        record = tmp_path / "record.txt"
        if peer == "pymodbus_slave.py":
            start_peer(peer, pty_pair.device, str(UNIT), "--silent-unknown", "--record",
                       str(record))
        else:
            start_peer(peer, pty_pair.device, "--record", str(record), "--late-ms", "300")
        udp_port, rtu_port = free_port(socket.SOCK_DGRAM), free_port()
        path = tmp_path / "mbgw.toml"
        path.write_text(f"[serial]\nbaudrate = 19200\n[net]\nudp-port = {udp_port}\n"
                        f"rtu-port = {rtu_port}\n" + text)
        gw = start_gateway(pty_pair.gateway, "--config", str(path), *options)
        return gw, udp_port, rtu_port, record
    return start


def udp_socket(timeout: float = REPLY_S) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(timeout)
    return sock


# --- Modbus/UDP ---

def test_a_pymodbus_udp_client_reads_the_serial_slave(faces):
    gw, udp_port, _, record = faces()
    client = ModbusUdpClient("127.0.0.1", port=udp_port, timeout=REPLY_S, retries=0)
    assert client.connect()
    try:
        reply = client.read_holding_registers(4, count=3, device_id=UNIT)
        assert not reply.isError() and reply.registers == [104, 105, 106]
        written = client.write_register(9, 77, device_id=UNIT)
        assert not written.isError()
    finally:
        client.close()
    assert on_the_wire(record) == ["11" + read(4, 3).hex(), "11" + write(9, 77).hex()]
    face = status(gw)["faces"]["udp"]
    assert (face["requests"], face["refused"], face["clients"]) == (2, 0, 1)


def test_a_retransmission_costs_one_line_transaction_and_gets_the_first_reply_again(faces):
    _, udp_port, _, record = faces()
    datagram = mbap(7, UNIT, read(0, 2))
    with udp_socket() as sock:
        sock.sendto(datagram, ("127.0.0.1", udp_port))
        first, source = sock.recvfrom(512)
        sock.sendto(datagram, ("127.0.0.1", udp_port))
        again, source_again = sock.recvfrom(512)
    assert first == again == struct.pack(">HHHB", 7, 0, 7, UNIT) + bytes.fromhex("0304 0064 0065")
    assert source[1] == source_again[1] == udp_port           # replies leave from udp-port
    assert on_the_wire(record) == ["11" + read(0, 2).hex()]


@pytest.mark.serial
def test_a_retransmission_while_the_first_is_outstanding_gets_nothing(
        tmp_path, pty_pair, second_pty, start_peer, start_gateway):
    """The request goes to line meters, whose thread waits for the late slave while line
    serial's thread, the face's home, reads the retransmission."""
    record = tmp_path / "meters.txt"
    start_peer("fault_slave.py", second_pty.device, "--record", str(record), "--late-ms", "300")
    udp_port = free_port(socket.SOCK_DGRAM)
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\nbaudrate = 19200\n[net]\nudp-port = {udp_port}\n'
                    f'[[line]]\nname = "meters"\ndevice = "{second_pty.gateway}"\n'
                    f'baudrate = 19200\nstout = 1000\n'
                    f'[[route]]\nunits = "3"\nline = "meters"\n')
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    datagram = mbap(9, 3, read(0, 1))           # address 3 answers after 300 ms
    with udp_socket() as sock:
        sock.sendto(datagram, ("127.0.0.1", udp_port))
        until(lambda: len(on_the_wire(record)) == 1, what="the request on the line",
              timeout=REPLY_S)
        sock.sendto(datagram, ("127.0.0.1", udp_port))
        until(lambda: status(gw)["faces"]["udp"]["retransmissions"] == 1,
              what="the retransmission seen", timeout=REPLY_S)
        assert sock.recvfrom(512)[0][7:] == bytes.fromhex("0302 03e8")
        sock.settimeout(SILENCE_S)
        with pytest.raises(TimeoutError):
            sock.recvfrom(512)
    assert len(on_the_wire(record)) == 1


def test_a_source_authip_refuses_gets_no_datagram_and_the_line_nothing(faces):
    gw, udp_port, _, record = faces("authip = [\"10.1.2.3\"]\n")
    with udp_socket(SILENCE_S) as sock:
        sock.sendto(mbap(1, UNIT, read(0, 1)), ("127.0.0.1", udp_port))
        with pytest.raises(TimeoutError):
            sock.recvfrom(512)
    assert on_the_wire(record) == []
    face = status(gw)["faces"]["udp"]
    assert (face["refused"], face["clients"], face["requests"]) == (1, 0, 0)


def test_a_firewall_rule_for_udp_refuses_silently_and_is_its_listeners_only(faces):
    gw, udp_port, rtu_port, record = faces(
        '[[rule]]\nlistener = "udp"\nread-only = true\nunits = "17"\n')
    with udp_socket(SILENCE_S) as sock:
        sock.sendto(mbap(1, UNIT, write(3, 5)), ("127.0.0.1", udp_port))     # refused
        with pytest.raises(TimeoutError):
            sock.recvfrom(512)
        sock.settimeout(REPLY_S)
        sock.sendto(mbap(2, UNIT, read(3, 1)), ("127.0.0.1", udp_port))
        assert sock.recvfrom(512)[0][7:] == bytes.fromhex("0302 0067")
    with socket.create_connection(("127.0.0.1", rtu_port), timeout=REPLY_S) as rtu:
        rtu.sendall(rtu_adu(UNIT, write(3, 5)))        # the rule is udp's: rtu may write
        assert rtu.recv(64) == rtu_adu(UNIT, write(3, 5))
    assert on_the_wire(record) == ["11" + read(3, 1).hex(), "11" + write(3, 5).hex()]
    s = status(gw)
    assert s["faces"]["udp"]["refused"] == 1 and s["firewall"]["rules"][0]["refused"] == 1


# --- RTU over TCP ---

def receive(sock: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        assert chunk, "connection closed"
        data += chunk
    return data


def test_a_pymodbus_rtu_framed_tcp_client_reads_and_writes(faces):
    _, _, rtu_port, record = faces()
    client = ModbusTcpClient("127.0.0.1", port=rtu_port, framer=FramerType.RTU,
                             timeout=REPLY_S, retries=0)
    assert client.connect()
    try:
        reply = client.read_holding_registers(1, count=2, device_id=UNIT)
        assert not reply.isError() and reply.registers == [101, 102]
        assert not client.write_register(2, 9, device_id=UNIT).isError()
    finally:
        client.close()
    assert on_the_wire(record) == ["11" + read(1, 2).hex(), "11" + write(2, 9).hex()]


def test_rtu_frames_end_by_length_and_crc_wherever_the_stream_is_cut(faces):
    gw, _, rtu_port, record = faces()
    first, second = rtu_adu(UNIT, read(0, 1)), rtu_adu(UNIT, read(5, 2))
    with socket.create_connection(("127.0.0.1", rtu_port), timeout=REPLY_S) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for byte in first:                              # one byte a segment
            sock.send(bytes((byte,)))
        assert receive(sock, 7) == rtu_adu(UNIT, bytes.fromhex("0302 0064"))
        sock.sendall(first + second)                    # two in one segment, in order
        assert receive(sock, 7) == rtu_adu(UNIT, bytes.fromhex("0302 0064"))
        assert receive(sock, 9) == rtu_adu(UNIT, bytes.fromhex("0304 0069 006a"))
    assert on_the_wire(record) == ["11" + read(0, 1).hex()] * 2 + ["11" + read(5, 2).hex()]
    assert status(gw)["faces"]["rtu"]["requests"] == 3


def test_a_bad_crc_is_dropped_and_counted_and_the_connection_stays_open(faces):
    gw, _, rtu_port, record = faces()
    good = rtu_adu(UNIT, read(0, 1))
    bad = good[:-1] + bytes((good[-1] ^ 0xFF,))
    with socket.create_connection(("127.0.0.1", rtu_port), timeout=REPLY_S) as sock:
        sock.sendall(bad + good)
        assert receive(sock, 7) == rtu_adu(UNIT, bytes.fromhex("0302 0064"))
    assert on_the_wire(record) == ["11" + read(0, 1).hex()]
    face = status(gw)["faces"]["rtu"]
    assert face["bad_frames"] == 1 and face["requests"] == 1


def test_the_trace_names_the_face_and_the_metrics_count_per_listener(faces):
    metrics_port = free_port()
    gw, udp_port, rtu_port, _ = faces("", "--metrics", f"127.0.0.1:{metrics_port}")
    stream = TraceStream(gw)
    try:
        with udp_socket() as sock:
            sock.sendto(mbap(3, UNIT, read(0, 1)), ("127.0.0.1", udp_port))
            sock.recvfrom(512)
            sock.sendto(mbap(3, UNIT, read(0, 1)), ("127.0.0.1", udp_port))  # again
            sock.recvfrom(512)
        with socket.create_connection(("127.0.0.1", rtu_port), timeout=REPLY_S) as rtu:
            rtu.sendall(rtu_adu(UNIT, read(1, 1)))
            receive(rtu, 7)
        events = stream.events(4)
    finally:
        stream.close()
    assert [(e["direction"], e["face"]) for e in events] == \
        [("request", "udp"), ("reply", "udp"), ("request", "rtu"), ("reply", "rtu")]
    families = scraped(metrics_port)
    assert metric_value(families, "mbgw_face_requests", "mbgw_face_requests_total",
                        listener="udp") == 1
    assert metric_value(families, "mbgw_face_retransmissions",
                        "mbgw_face_retransmissions_total", listener="udp") == 1
    assert metric_value(families, "mbgw_face_requests", "mbgw_face_requests_total",
                        listener="rtu") == 1
    text = mbgw("status", "--control", gw.control).stdout
    assert "udp 1 client, 1 requests (1 again); rtu " in text
    assert re.search(r"rtu \d clients?, 1 requests", text), text


def test_a_reload_judges_each_udp_source_again_and_a_new_udp_port_waits_for_a_restart(
        faces):
    gw, udp_port, _, record = faces()
    path = Path(next(a for a in gw.args if a.endswith("mbgw.toml")))
    with udp_socket() as sock:
        sock.sendto(mbap(1, UNIT, read(0, 1)), ("127.0.0.1", udp_port))
        assert sock.recvfrom(512)[0][7:] == bytes.fromhex("0302 0064")
        path.write_text(path.read_text().replace(
            f"udp-port = {udp_port}", f"udp-port = {free_port()}\nauthip = [\"10.1.2.3\"]"))
        reload(gw, "udp-port: takes effect at restart")
        sock.settimeout(SILENCE_S)
        sock.sendto(mbap(2, UNIT, read(0, 1)), ("127.0.0.1", udp_port))   # still there
        with pytest.raises(TimeoutError):
            sock.recvfrom(512)
    assert len(on_the_wire(record)) == 1
    assert status(gw)["faces"]["udp"]["refused"] == 1
