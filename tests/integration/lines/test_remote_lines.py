"""Lines beyond the local serial port (issue 26): a `[[line]]` whose device is across the
network (`connect`), reached from the Modbus TCP face like any other line.

Peers that are not ours: a device emulator that takes one TCP connection and resets any
other (tests/peers/single_client_device.py, Modbus TCP or RTU frames, its replies late,
twice, cut in 1-byte segments or joined), a pymodbus RTU slave behind socat's TCP listener,
pymodbus's Modbus/UDP server, raw sockets and pymodbus/mbpoll clients in front.
"""
import os
import signal
import socket
import struct
import subprocess
import threading

import pytest
from pymodbus.client import ModbusTcpClient

from tests.harness import free_port, stop
from tests.integration.lines.conftest import INVERTER, STOUT_MS
from tests.modbus import Client, mbap, read_holding
from tests.ops import mbgw, metric_value, scraped, status, wait_for, wait_for_log
from tests.peers.single_client_device import LATE_REGISTER, TWICE_REGISTER, SingleClientDevice
from tests.wait import until

pytestmark = pytest.mark.integration



def reply(start: int, count: int) -> bytes:
    """The emulator's: holding register n holds 100 + n."""
    return bytes((0x03, 2 * count)) + b"".join(struct.pack(">H", 100 + start + i)
                                                for i in range(count))


def test_a_modbus_tcp_device_answers_through_its_line(remote_gateway, client, device):
    d = device(delays=(0.005, 0.02))
    gw = remote_gateway(d.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(3, 4)) == reply(3, 4)
    assert c.ask(INVERTER + 1, read_holding(0, 1)) == reply(0, 1)
    assert d.requests == [(INVERTER, read_holding(3, 4)), (INVERTER + 1, read_holding(0, 1))]
    s = status(gw)
    row = next(r for r in s["lines"] if r["name"] == "inverter")
    assert (row["state"], row["device"]) == ("up", d.url)
    assert (d.connections, d.resets) == (1, 0)


def counter(s: dict, name: str) -> int:
    """Line inverter's counter name in status s."""
    return next(r for r in s["lines"] if r["name"] == "inverter")["counters"][name]


@pytest.mark.serial
def test_late_and_duplicate_replies_are_dropped_and_counted(remote_gateway, client, device):
    d = device(delays=(0.005, 0.01), late_s=STOUT_MS / 1000 + 0.2)
    gw = remote_gateway(d.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(LATE_REGISTER, 2)) == b"\x83\x0b"   # too late
    # the same read again: the late reply to the first comes meanwhile, under its own tid
    assert c.ask(INVERTER, read_holding(TWICE_REGISTER, 2)) == reply(TWICE_REGISTER, 2)
    assert c.ask(INVERTER, read_holding(7, 2)) == reply(7, 2)   # not the duplicate
    wait_for(gw, lambda s: counter(s, "stray_replies") == 2,
             "the late reply and the duplicate counted stray")
    assert (d.connections, d.resets) == (1, 0)


def test_a_connection_the_device_closed_is_opened_again_at_once(remote_gateway, client, device):
    d = device(delays=(0.001, 0.002))
    metrics_port = free_port()
    gw = remote_gateway(d.url, "--metrics", f"127.0.0.1:{metrics_port}")
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    d.close_connection()
    assert c.ask(INVERTER, read_holding(1, 1)) == reply(1, 1)
    s = wait_for(gw, lambda s: counter(s, "reconnects") == 1, "one reconnect")
    assert next(r for r in s["lines"] if r["name"] == "inverter")["state"] == "up"
    assert (d.connections, d.resets) == (2, 0)
    assert "lost" not in gw.log()
    text = mbgw("status", "--control", gw.control).stdout
    assert f"{d.url} (slave, 1 reconnects, 0 stray replies)" in text, text
    families = scraped(metrics_port)
    assert metric_value(families, "mbgw_line_reconnects", "mbgw_line_reconnects_total",
                        line="inverter") == 1
    assert metric_value(families, "mbgw_line_stray_replies",
                        "mbgw_line_stray_replies_total", line="inverter") == 0
    assert metric_value(families, "mbgw_line_up", line="inverter", mode="slave") == 1


def test_an_unreachable_device_is_0x0a_logged_once_and_once_back(remote_gateway, client):
    port = free_port()                 # nothing listens there: refused
    gw = remote_gateway(f"modbus-tcp://127.0.0.1:{port}")
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == b"\x83\x0a"
    assert c.ask(INVERTER, read_holding(0, 1)) == b"\x83\x0a"     # in backoff: at once
    wait_for(gw, lambda s: next(r for r in s["lines"] if r["name"] == "inverter")[
        "state"] == "down", "line inverter down")
    assert c.ask(5, read_holding(0, 1))[0] == 0x03          # line serial answers meanwhile
    back = SingleClientDevice(delays=(0.001, 0.002), port=port)
    try:
        def answered() -> bool:
            return c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
        until(answered, "the device answers after the backoff", timeout=10)
        wait_for_log(gw, "answers again")
        assert gw.log().count("lost: ") == 1
        assert status(gw)["lines"][1]["state"] == "up"
    finally:
        back.stop()


def pipelining(port: int, first: int, count: int, wrong: list, errors: list) -> None:
    """count reads in flight, 4 at a time, each of its own registers: a reply of another's
    registers is a wrong delivery."""
    try:
        c = Client(port)
        try:
            for at in range(0, count, 4):
                frames = [struct.pack(">HHHB", tid, 0, 6, INVERTER) + read_holding(first + tid, 1)
                          for tid in range(at, at + 4)]
                c.send(*frames)
                for tid in range(at, at + 4):
                    got = c.recv()
                    if got != (tid, INVERTER, reply(first + tid, 1)):
                        wrong.append(got)
        finally:
            c.close()
    except BaseException as err:
        errors.append(err)


def pymodbus_reads(port: int, first: int, count: int, wrong: list, errors: list) -> None:
    try:
        with ModbusTcpClient("127.0.0.1", port=port, timeout=5, retries=0) as tcp:
            for n in range(count):
                got = tcp.read_holding_registers(first + n, count=2, device_id=INVERTER)
                if got.isError() or got.registers != [100 + first + n, 101 + first + n]:
                    wrong.append(got)
    except BaseException as err:
        errors.append(err)


def mbpoll_reads(port: int, first: int, count: int, wrong: list, errors: list) -> None:
    try:
        for n in range(count):
            out = subprocess.run(["mbpoll", "-m", "tcp", "-a", str(INVERTER), "-p", str(port),
                                  "-0", "-t", "4", "-r", str(first + n), "-c", "2", "-1",
                                  "127.0.0.1"], capture_output=True, text=True, timeout=10)
            if f"[{first + n}]: \t{100 + first + n}" not in out.stdout:
                wrong.append(out.stdout + out.stderr)
    except BaseException as err:
        errors.append(err)


@pytest.mark.serial
def test_eight_pipelining_clients_each_get_their_own_replies(remote_gateway, device):
    """6 raw clients with 4 requests in flight each, a pymodbus client and mbpoll, at once,
    on a device that answers in 1-10 ms and takes one connection."""
    d = device(delays=(0.001, 0.01))
    gw = remote_gateway(d.url, "--max-connections", "16", "--max-connections-per-ip", "16")
    wrong: list = []
    errors: list = []
    jobs = [(pipelining, 100 * n, 12) for n in range(6)] + \
        [(pymodbus_reads, 600, 10), (mbpoll_reads, 700, 5)]
    threads = [threading.Thread(target=job, args=(gw.port, first, count, wrong, errors))
               for job, first, count in jobs]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, (errors, gw.log())
    assert wrong == []
    assert len(d.requests) == 6 * 12 + 10 + 5
    assert (d.connections, d.resets) == (1, 0)


def test_a_read_only_clients_write_is_refused_and_never_reaches_the_device(
        remote_gateway, client, device):
    d = device(delays=(0.001, 0.002))
    gw = remote_gateway(d.url, rules='[[rule]]\nclient = "127.0.0.1"\nread-only = true\n')
    c = client(gw)
    assert c.ask(INVERTER, bytes.fromhex("06 0001 1234")) == b"\x86\x01"
    assert c.ask(INVERTER, read_holding(1, 1)) == reply(1, 1)
    assert d.requests == [(INVERTER, read_holding(1, 1))]


@pytest.mark.serial
@pytest.mark.parametrize("segments", ["bytes", "join"])
def test_rtu_over_tcp_frames_by_length_and_crc_never_by_silence(remote_gateway, client, device,
                                                                 segments):
    d = device(framing="rtu", delays=(0.001, 0.005), segments=segments)
    gw = remote_gateway(d.url)
    c = client(gw)
    if segments == "join":       # the late reply comes in one segment with the next one's
        assert c.ask(INVERTER, read_holding(LATE_REGISTER, 3)) == b"\x83\x0b"
    for start in range(5):
        assert c.ask(INVERTER, read_holding(start, 2)) == reply(start, 2)
    s = status(gw)
    assert counter(s, "stray_replies") == (1 if segments == "join" else 0)
    assert (d.connections, d.resets) == (1, 0)


class DeviceServer:
    """A serial device server, socat's: a pty for a pymodbus RTU slave, its bytes to and from
    one TCP (or UDP) peer."""

    def __init__(self, directory, start_peer, address: int, transport: str = "tcp") -> None:
        self.port = free_port()
        self.tty = str(directory / "ttyDS")
        self.proc = subprocess.Popen(
            ["socat", "-d", "-d", f"pty,raw,echo=0,link={self.tty}",
             f"{transport}-listen:{self.port},reuseaddr"], stderr=subprocess.PIPE, text=True)
        until(lambda: os.path.exists(self.tty), "socat's pty", timeout=10)
        self.slave = start_peer("pymodbus_slave.py", self.tty, str(address), "--silent-unknown")

    def stop(self) -> None:
        stop(self.proc)


@pytest.fixture
def device_server(tmp_path, start_peer):
    servers: list[DeviceServer] = []

    def start(address: int, transport: str = "tcp") -> DeviceServer:
        servers.append(DeviceServer(tmp_path, start_peer, address, transport))
        return servers[-1]
    yield start
    for s in servers:
        s.stop()


@pytest.mark.parametrize("transport", ["tcp", "udp"])
def test_a_pymodbus_rtu_slave_behind_socat_answers(remote_gateway, client, device_server,
                                                   transport):
    server = device_server(INVERTER, transport)
    gw = remote_gateway(f"rtu-over-{transport}://127.0.0.1:{server.port}")
    c = client(gw)
    for start in (0, 10, 50):
        assert c.ask(INVERTER, read_holding(start, 3)) == reply(start, 3)
    assert c.ask(INVERTER + 1, read_holding(0, 1)) == b"\x83\x0b"    # nobody at 41


def test_a_modbus_udp_device_answers(remote_gateway, client, start_peer):
    port = free_port()
    start_peer("pymodbus_udp_server.py", str(port), str(INVERTER))
    gw = remote_gateway(f"modbus-udp://127.0.0.1:{port}")
    c = client(gw)
    for start in (0, 10, 50):
        assert c.ask(INVERTER, read_holding(start, 3)) == reply(start, 3)


def test_a_datagram_from_another_port_is_never_a_reply(remote_gateway, client):
    """A UDP 'device' that answers from another socket (another port): its reply is no
    reply; the request gets 0x0B."""
    device = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    device.bind(("127.0.0.1", 0))
    impostor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    impostor.bind(("127.0.0.1", 0))
    gw = remote_gateway(f"modbus-udp://127.0.0.1:{device.getsockname()[1]}")
    c = client(gw)
    try:
        c.send(mbap(1, INVERTER, read_holding(0, 1)))
        device.settimeout(5)
        request, source = device.recvfrom(300)
        answer = request[:4] + struct.pack(">HB", 5, INVERTER) + reply(0, 1)
        impostor.sendto(answer, source)
        assert c.recv() == (1, INVERTER, b"\x83\x0b")
        c.send(mbap(2, INVERTER, read_holding(0, 1)))
        request, source = device.recvfrom(300)
        device.sendto(request[:4] + struct.pack(">HB", 5, INVERTER) + reply(0, 1), source)
        assert c.recv() == (2, INVERTER, reply(0, 1))
    finally:
        device.close()
        impostor.close()


def test_a_reload_moves_the_line_to_another_device(tmp_path, remote_gateway, client, device):
    first, second = device(delays=(0.001, 0.002)), device(delays=(0.001, 0.002))
    gw = remote_gateway(first.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(0, 1)) == reply(0, 1)
    path = tmp_path / "mbgw.toml"
    path.write_text(path.read_text().replace(first.url, second.url))
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: lines changed")
    assert c.ask(INVERTER, read_holding(1, 1)) == reply(1, 1)
    assert first.requests == [(INVERTER, read_holding(0, 1))]
    assert second.requests == [(INVERTER, read_holding(1, 1))]
    until(lambda: first.connections == 1 and first.open is None, "the first device let go",
          timeout=10)
    row = next(r for r in status(gw)["lines"] if r["name"] == "inverter")
    assert row["device"] == second.url


def test_ascii_over_tcp_with_noise_before_the_reply(remote_gateway, client):
    """A raw ASCII device server: each request answered after a burst of noise."""
    listener = socket.create_server(("127.0.0.1", free_port()))
    seen: list[bytes] = []

    def serve() -> None:
        conn, _ = listener.accept()
        with conn:
            while (request := conn.recv(512)):
                seen.append(request)
                adu = bytes.fromhex(request[1:-4].decode())
                answer = bytes((adu[0],)) + reply(adu[3], adu[5])
                lrc = (-sum(answer)) & 0xFF
                frame = b":" + (answer + bytes((lrc,))).hex().upper().encode() + b"\r\n"
                conn.sendall(b"\x00\xfe noise" + frame[:7])
                conn.sendall(frame[7:])
    threading.Thread(target=serve, daemon=True).start()
    try:
        gw = remote_gateway(f"ascii-over-tcp://127.0.0.1:{listener.getsockname()[1]}")
        c = client(gw)
        assert c.ask(INVERTER, read_holding(3, 2)) == reply(3, 2)
        assert c.ask(INVERTER, read_holding(9, 1)) == reply(9, 1)
        assert seen[0] == b":2803000300" + b"02" + b"%02X" % ((-(0x28 + 3 + 3 + 2)) & 0xFF) + \
            b"\r\n"
    finally:
        listener.close()
