"""The Modbus TCP face of a master-mode daemon (issue 24): `[[route]]`s without `from` make
`mbgw master` listen on mdbport, while line serial stays a serial face.  A pymodbus TCP client
reads a meter on a [[line]] in slave mode through it (unit 32 is the meter's address 1) while
line serial's serial master reads the same meter; unit 200 reaches the exchange table; a unit
no route takes gets 0x0A at once and reaches no line; status and `mbgw clients` show the
face's clients, the trace its transactions, /metrics its clients; it listens on the TLS port,
udp-port and rtu-port too; a reload that brings the first TCP route starts the face.

Peers that are not ours: a recording pymodbus RTU slave on a socat pty pair (the meter), a
pymodbus TCP client, and raw frames written by the test (the serial master, and a unit no
route takes), each answer checked byte for byte."""
import os
import signal
import socket

import pytest
from pymodbus.client import ModbusTcpClient, ModbusUdpClient
from pymodbus.framer import FramerType

from tests.harness import free_port
from tests.integration.lines.test_lines import METER, METER_UNIT, hr_reply, received
from tests.integration.lines.test_lines_observed import TraceStream
from tests.integration.lines.test_lines_of_both_modes import (
    BAUD,
    SERIAL_ROUTE,
    meters,  # noqa: F401 (the fixture)
    meters_line,
)
from tests.integration.master.test_serial_faces import ask, lines_file, read
from tests.integration.tls.test_tls import client_context, tls_client, tls_options
from tests.modbus import REPLY_S, read_holding
from tests.ops import mbgw, metric_value, scraped, status, wait_for_log
from tests.pki import Authority

pytestmark = pytest.mark.integration

TABLE_UNIT = 200
UNROUTED = 7
TCP_ROUTES = [{"units": list(range(32, 64)), "line": "meters", "offset": -31},
              {"units": [TABLE_UNIT], "table": True}]


@pytest.fixture
def face_daemon(tmp_path, start_gateway, pty_pair, meters):  # noqa: F811
    """`mbgw master` on pty_pair, its TCP face on 127.0.0.1 (mdbport), the table on."""
    config = lines_file(tmp_path / "lines.toml", [meters_line(meters)],
                        [SERIAL_ROUTE, *TCP_ROUTES])
    return start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", str(BAUD),
                         "--exception", "--table", "--table-port", str(free_port()),
                         mode="master")


def test_a_tcp_client_reads_a_line_in_slave_mode_of_a_master_mode_daemon(
        face_daemon, meters, pty_pair, open_line, client):  # noqa: F811
    gw = face_daemon
    with ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0) as tcp:
        got = tcp.read_holding_registers(0, count=2, device_id=METER_UNIT)
        assert not got.isError(), got
        assert got.registers == [100, 101]
        master = open_line(pty_pair.device)     # line serial's master reads the same meter
        ask(master, read(METER_UNIT, 5, 1), bytes((METER_UNIT,)) + hr_reply(5, 1))
        assert not tcp.write_register(0x100, 0x1234, device_id=TABLE_UNIT).isError()
        got = tcp.read_holding_registers(0x100, count=1, device_id=TABLE_UNIT)
        assert got.registers == [0x1234]
        # a unit no route takes: 0x0A at once, nothing on any line
        assert client(gw).ask(UNROUTED, read_holding(0, 1)) == bytes((0x83, 0x0A))
        assert received(meters.record) == [bytes((METER,)) + read_holding(0, 2),
                                           bytes((METER,)) + read_holding(5, 1)]
        s = status(gw)
        assert s["mode"] == "master"
        assert any(str(gw.port) in a for a in s["listening"])
        assert len(s["tcp_clients"]) == 2
        assert s["tcp_counters"]["unroutable"] == 1
        text = mbgw("clients", "--control", gw.control)
        assert text.returncode == 0, text.stderr
        assert "clients (2)" in text.stdout and "table clients (0)" in text.stdout
        text = mbgw("status", "--control", gw.control)
        assert text.returncode == 0, text.stderr
        assert "the Modbus TCP face" in text.stdout
    assert "Modbus TCP face: listening on" in gw.log()


def test_the_face_is_traced_and_metered(tmp_path, start_gateway, pty_pair, meters,  # noqa: F811
                                        client):
    metrics_port = free_port()
    config = lines_file(tmp_path / "lines.toml", [meters_line(meters)], TCP_ROUTES[:1])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", str(BAUD),
                       "--metrics", f"127.0.0.1:{metrics_port}", mode="master")
    stream = TraceStream(gw)
    try:
        c = client(gw)
        assert c.ask(METER_UNIT, read_holding(1, 1)) == hr_reply(1, 1)
        request, reply = stream.events(2)
    finally:
        stream.close()
    assert (request["direction"], request["line"], request["unit"], request["pdu"]) == \
        ("request", "meters", METER_UNIT, read_holding(1, 1).hex())
    assert (reply["direction"], reply["line"], reply["pdu"]) == \
        ("reply", "meters", hr_reply(1, 1).hex())
    assert request["peer"] == reply["peer"] == status(gw)["tcp_clients"][0]["peer"]
    families = scraped(metrics_port)
    assert metric_value(families, "mbgw_clients_connected") == 1


def test_a_reload_brings_the_tcp_face(tmp_path, start_gateway, pty_pair, meters):  # noqa: F811
    config = lines_file(tmp_path / "lines.toml", [meters_line(meters)], [SERIAL_ROUTE])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", str(BAUD),
                       mode="master")
    assert "listening" not in status(gw)
    lines_file(config, [meters_line(meters)], [SERIAL_ROUTE, *TCP_ROUTES[:1]])
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded")
    with ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S, retries=0) as tcp:
        got = tcp.read_holding_registers(3, count=1, device_id=METER_UNIT)
        assert not got.isError(), got
        assert got.registers == [103]
    assert received(meters.record) == [bytes((METER,)) + read_holding(3, 1)]


def test_the_face_listens_on_the_tls_port_too(tmp_path, start_gateway, pty_pair,
                                              meters):  # noqa: F811
    ca = Authority(tmp_path)
    tls_port = free_port()
    config = lines_file(tmp_path / "lines.toml", [meters_line(meters)], TCP_ROUTES[:1])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", str(BAUD),
                       *tls_options(ca, ca.issue("server", server=True), tls_port),
                       mode="master")
    tls = tls_client(tls_port, client_context(ca, ca.issue("op", role="operator")))
    try:
        got = tls.read_holding_registers(2, count=1, device_id=METER_UNIT)
        assert not got.isError(), got
        assert got.registers == [102]
        [row] = status(gw)["tcp_clients"]
        assert (row["listener"], row["role"]) == ("tls", "operator")
    finally:
        tls.close()


def test_the_face_takes_modbus_udp_and_rtu_over_tcp_too(tmp_path, start_gateway, pty_pair,
                                                        meters):  # noqa: F811
    """udp-port and rtu-port in a master-mode daemon with the TCP face: its routes (unit 32
    is the meter's address 1) on both."""
    udp_port, rtu_port = free_port(socket.SOCK_DGRAM), free_port()
    config = lines_file(tmp_path / "lines.toml", [meters_line(meters)], TCP_ROUTES[:1])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", str(BAUD),
                       "--udp-port", str(udp_port), "--rtu-port", str(rtu_port),
                       mode="master")
    udp = ModbusUdpClient("127.0.0.1", port=udp_port, timeout=REPLY_S, retries=0)
    rtu = ModbusTcpClient("127.0.0.1", port=rtu_port, framer=FramerType.RTU,
                          timeout=REPLY_S, retries=0)
    try:
        assert udp.connect() and rtu.connect()
        assert udp.read_holding_registers(4, count=1, device_id=METER_UNIT).registers == [104]
        assert rtu.read_holding_registers(6, count=1, device_id=METER_UNIT).registers == [106]
    finally:
        udp.close()
        rtu.close()
    assert received(meters.record) == [bytes((METER,)) + read_holding(4, 1),
                                       bytes((METER,)) + read_holding(6, 1)]
    faces = status(gw)["faces"]
    assert faces["udp"]["requests"] == faces["rtu"]["requests"] == 1
