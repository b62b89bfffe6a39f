"""Transparent mode (issue 16, VPGate 3.8): a device that speaks no Modbus on a socat pty
exchanges raw frames with Modbus TCP clients through the exchange table.

The device is scripted here (`Device`: raw bytes on the pty's other end); the TCP client is
pymodbus.  Every expected register content and wire frame is built by the test from the rules
(two bytes to a register, the first high; the CRC from tests/modbus.py), never by mbgw's code.
"Nothing sent" is checked by order: a frame that must be sent follows the one that must not,
and the device's next bytes must be it."""
import os
import re
import select
import signal
import socket
import subprocess
import sys
import time
import urllib.request

import prometheus_client.parser
import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException

from tests.harness import free_port
from tests.modbus import crc16
from tests.ops import mbgw, metric_families, metric_value, status, wait_for, wait_for_log

pytestmark = pytest.mark.integration

REPLY_S = 3.0
RX, TX = 0, 2048                     # the default areas
EOF_TIMEOUT = "60"                   # ms: a frame written at once never pauses this long


class Device:
    """The serial device: the far end of the pty, raw bytes."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

    def send(self, data: bytes) -> None:
        os.write(self.fd, data)

    def read(self, n: int) -> bytes:
        """Exactly n bytes, within REPLY_S."""
        data = b""
        deadline = time.monotonic() + REPLY_S
        while len(data) < n:
            left = deadline - time.monotonic()
            assert left > 0, f"the device got {data!r}, not {n} bytes"
            if select.select([self.fd], [], [], left)[0]:
                data += os.read(self.fd, n - len(data))
        return data

    def pending(self) -> bytes:
        """What has come and not been read (nothing waits: called once the gateway's
        counters say it has sent all it will)."""
        try:
            return os.read(self.fd, 4096)
        except BlockingIOError:
            return b""

    def close(self) -> None:
        os.close(self.fd)


@pytest.fixture
def transparent(pty_pair, start_gateway):
    """transparent(*options) -> (gateway, device, pymodbus client on mdbport)."""
    opened = []

    def start(*options: str):
        gw = start_gateway(pty_pair.gateway, "--eof-timeout", EOF_TIMEOUT, *options,
                           mode="transparent")
        device = Device(pty_pair.device)
        client = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S)
        assert client.connect()
        opened.append((device, client))
        return gw, device, client

    yield start
    for device, client in opened:
        client.close()
        device.close()


def registers(data: bytes, size: int) -> list[int]:
    """The registers an area of size bytes holds: data, then zeros; two bytes a register, the
    first in the high half."""
    data = data.ljust(size + size % 2, b"\0")
    return [data[i] << 8 | data[i + 1] for i in range(0, len(data), 2)]


def read_area(client, address: int, size: int) -> list[int]:
    reply = client.read_holding_registers(address, count=(size + 1) // 2)
    assert not reply.isError(), reply
    return reply.registers


def write_area(client, address: int, data: bytes, size: int) -> None:
    reply = client.write_registers(address, registers(data, size))
    assert not reply.isError(), reply


def counters(gw, **expected) -> dict:
    """The status once its counters have the expected values."""
    return wait_for(gw, lambda s: all(s["counters"][k] == v for k, v in expected.items()),
                    f"counters {expected}")


END_CHARACTERS = [("nul", b"\0", ()), ("space", b" ", ()), ("lf", b"\n", ()),
                  ("cr", b"\r", ()), ("crlf", b"\r\n", ()), ("lfcr", b"\n\r", ()),
                  ("char", b"\x03", ("--eof-char", "3"))]


@pytest.mark.parametrize("eof, end, options", END_CHARACTERS, ids=[e[0] for e in END_CHARACTERS])
def test_end_character_frames_both_ways(transparent, eof, end, options):
    gw, device, client = transparent("--eof", eof, "--rx-size", "16", "--tx-size", "16",
                                     *options)
    device.send(b"W+12.5kg" + end + b"ST" + end)          # two frames in one burst
    counters(gw, frames_stored=2)
    assert read_area(client, RX, 16) == registers(b"ST" + end, 16)   # the last one, zero-filled
    write_area(client, TX, b"?P" + end + b"after", 16)   # sent up to and including the end
    assert device.read(2 + len(end)) == b"?P" + end
    counters(gw, frames_sent=1)
    write_area(client, TX, b"?Q" + end, 16)
    assert device.read(2 + len(end)) == b"?Q" + end
    counters(gw, frames_sent=2)
    assert device.pending() == b""


def test_length_byte_frames_and_a_length_beyond_the_area(transparent):
    gw, device, client = transparent("--eof", "length", "--rx-size", "8", "--tx-size", "6")
    device.send(bytes([3]) + b"abc" + bytes([0]))           # a frame, then an empty one
    counters(gw, frames_stored=2)
    assert read_area(client, RX, 8) == registers(bytes([0]), 8)
    device.send(bytes([3]) + b"xyz")
    counters(gw, frames_stored=3)
    assert read_area(client, RX, 8) == registers(bytes([3]) + b"xyz", 8)
    write_area(client, TX, bytes([6]) + b"12345", 6)       # 6 bytes after it: beyond the area
    counters(gw, sends_refused=1)
    write_area(client, TX, bytes([2]) + b"OKjunk"[:5], 6)  # the length byte is sent too
    assert device.read(3) == bytes([2]) + b"OK"
    counters(gw, frames_sent=1, sends_refused=1)
    assert device.pending() == b""


def test_timeout_frames_length_in_the_first_byte(transparent):
    gw, device, client = transparent("--eof", "timeout", "--rx-size", "10", "--tx-size", "8")
    device.send(b"hello")
    counters(gw, frames_stored=1)
    assert read_area(client, RX, 10) == registers(bytes([5]) + b"hello", 10)
    write_area(client, TX, bytes([8]) + b"abcdefg", 8)       # 8 bytes do not fit after it
    counters(gw, sends_refused=1)
    write_area(client, TX, bytes([3]) + b"abcXYZ", 8)       # the length byte is not sent
    assert device.read(3) == b"abc"
    counters(gw, frames_sent=1)
    assert device.pending() == b""


def test_a_frame_longer_than_the_area_is_stored_cut_and_counted(transparent):
    gw, device, client = transparent("--eof", "cr", "--rx-size", "5")
    device.send(b"0123456789\r")
    counters(gw, frames_stored=1, frames_truncated=1)
    assert read_area(client, RX, 5) == registers(b"01234", 5)


def test_timeout_truncation_keeps_the_length_byte_of_what_is_stored(transparent):
    gw, device, client = transparent("--eof", "timeout", "--rx-size", "4")
    device.send(b"abcdef")
    counters(gw, frames_stored=1, frames_truncated=1)
    assert read_area(client, RX, 4) == registers(bytes([3]) + b"abc", 4)


def test_an_incomplete_frame_is_dropped_and_counted(transparent):
    gw, device, client = transparent("--eof", "crlf", "--rx-size", "8")
    device.send(b"abc\r")                                    # quiet before the LF
    counters(gw, frames_incomplete=1)
    device.send(b"de\r\n")
    s = counters(gw, frames_stored=1)
    assert read_area(client, RX, 8) == registers(b"de\r\n", 8)
    assert s["counters"]["frames_received"] == 1


def test_incomplete_length_frame(transparent):
    gw, device, client = transparent("--eof", "length", "--rx-size", "8")
    device.send(bytes([5]) + b"ab")
    counters(gw, frames_incomplete=1)
    device.send(bytes([1]) + b"z")
    counters(gw, frames_stored=1)
    assert read_area(client, RX, 8) == registers(bytes([1]) + b"z", 8)


@pytest.mark.parametrize("eof", ["cr", "length", "timeout"])
def test_crc_checked_on_receipt_and_added_when_sending(transparent, eof):
    gw, device, client = transparent("--eof", eof, "--crc", "--rx-size", "8", "--tx-size", "8")
    frame = {"cr": b"AB\r", "length": bytes([2]) + b"AB", "timeout": b"AB"}[eof]
    bad = frame + bytes(b ^ 0xFF for b in crc16(frame))
    device.send(bad)
    counters(gw, crc_errors=1)
    device.send(frame + crc16(frame))
    counters(gw, frames_stored=1, crc_errors=1)
    stored = bytes([2]) + b"AB" if eof == "timeout" else frame
    assert read_area(client, RX, 8) == registers(stored, 8)
    out = {"cr": b"OK\r", "length": bytes([2]) + b"OK", "timeout": b"OK"}[eof]
    area = bytes([2]) + b"OK" if eof == "timeout" else out
    write_area(client, TX, area, 8)
    assert device.read(len(out) + 2) == out + crc16(out)


def test_crc_off_stores_the_frame_as_it_came(transparent):
    gw, device, client = transparent("--eof", "timeout", "--rx-size", "8")
    frame = b"AB" + b"\x00\x00"                              # no CRC expected: all data
    device.send(frame)
    counters(gw, frames_stored=1)
    assert read_area(client, RX, 8) == registers(bytes([4]) + frame, 8)


def test_trigger_counts_received_frames_and_sends_on_a_new_counter(transparent):
    gw, device, client = transparent("--eof", "cr", "--trigger", "--rx-size", "8",
                                     "--tx-size", "8")
    device.send(b"one\r")
    counters(gw, frames_stored=1)
    assert read_area(client, RX, 8) == registers(bytes([1]) + b"one\r", 8)
    device.send(b"two\r")
    counters(gw, frames_stored=2)
    assert read_area(client, RX, 8) == registers(bytes([2]) + b"two\r", 8)
    write_area(client, TX, bytes([1]) + b"A\r", 8)          # a new counter: sent
    assert device.read(2) == b"A\r"
    write_area(client, TX, bytes([1]) + b"B\r", 8)          # the same counter: nothing
    write_area(client, TX, bytes([2]) + b"C\r", 8)          # a new one: sent
    assert device.read(2) == b"C\r"
    counters(gw, frames_sent=2)
    assert device.pending() == b""


def test_silence_after_a_received_frame_before_sending(transparent):
    gw, device, client = transparent("--eof", "cr", "--interframe-silence", "400",
                                     "--tx-size", "8")
    device.send(b"ping\r")
    received = time.monotonic()
    counters(gw, frames_stored=1)       # the frame is in: the silence after it is owed
    write_area(client, TX, b"pong\r", 8)
    assert device.read(5) == b"pong\r"
    assert time.monotonic() - received >= 0.4      # a lower bound: load only lengthens it


def test_raw_port_streams_both_ways_one_client_at_a_time(transparent):
    raw_port = free_port()
    gw, device, client = transparent("--eof", "cr", "--raw-port", str(raw_port))
    raw = socket.create_connection(("127.0.0.1", raw_port), timeout=REPLY_S)
    wait_for(gw, lambda s: s["transparent"]["raw_client"] is not None, "a raw client")
    second = socket.create_connection(("127.0.0.1", raw_port), timeout=REPLY_S)
    assert second.recv(16) == b""                           # refused: closed at once
    second.close()
    wait_for_log(gw, "refused")
    device.send(b"12.5kg\r")
    assert raw.recv(64) == b"12.5kg\r"                      # and stored in the table too
    counters(gw, frames_stored=1, raw_refused=1)
    raw.sendall(b"?\r")
    assert device.read(2) == b"?\r"
    raw.shutdown(socket.SHUT_WR)                            # done sending, as `socat -t` is
    device.send(b"13.0kg\r")
    assert raw.recv(64) == b"13.0kg\r"                      # still gets the frames
    third = socket.create_connection(("127.0.0.1", raw_port), timeout=REPLY_S)
    wait_for_log(gw, "gives way to")                        # ...until another client comes
    assert raw.recv(64) == b""
    device.send(b"14.0kg\r")
    assert third.recv(64) == b"14.0kg\r"
    third.close()
    raw.close()


def test_a_raw_client_that_closed_is_noticed_without_a_newcomer(transparent):
    """A client that closed looks, to the gateway, like one done sending (socat -t) until a
    frame reaches it and it answers with a reset: then it is gone from the status at once,
    not when the next client comes.  The status names the line without a Modbus framing."""
    raw_port = free_port()
    gw, device, _ = transparent("--eof", "cr", "--raw-port", str(raw_port))
    raw = socket.create_connection(("127.0.0.1", raw_port), timeout=REPLY_S)
    peer = "%s:%d" % raw.getsockname()[:2]
    wait_for(gw, lambda s: s["transparent"]["raw_client"] == peer, "the raw client")
    shown = mbgw("status", "--control", gw.control).stdout
    assert f"raw        port {raw_port}, client {peer}\n" in shown + "\n", shown
    assert re.search(r"^serial     \S+ \d+ 8n1 rs232: line up$", shown, re.M), shown
    raw.close()
    wait_for(gw, lambda s: not s["transparent"]["raw_client_sending"], "its end of sending")
    assert "done sending" in mbgw("clients", "--control", gw.control).stdout
    device.send(b"12.5kg\r")                     # reaches the closed client: a reset back
    wait_for(gw, lambda s: s["transparent"]["raw_client"] is None, "the closed client gone")
    wait_for_log(gw, f"raw client {peer} disconnected")


def test_authip_applies_to_the_table_and_the_raw_port(transparent):
    raw_port = free_port()
    gw, device, client = transparent("--authip", "192.0.2.1", "--raw-port", str(raw_port))
    for port in (gw.port, raw_port):
        refused = socket.create_connection(("127.0.0.1", port), timeout=REPLY_S)
        try:
            assert refused.recv(16) == b""               # closed at once
        except ConnectionResetError:
            pass
        refused.close()
    log = wait_for_log(gw, "raw client 127.0.0.1")
    assert "not in authip" in log
    assert status(gw)["table"]["tcp"]["connections_refused_authip"] >= 1


def test_counters_in_metrics_and_the_trace_shows_frames_in_hex(transparent):
    metrics_port = free_port()
    gw, device, client = transparent("--eof", "cr", "--metrics", f"127.0.0.1:{metrics_port}")
    trace = subprocess.Popen([sys.executable, "-m", "mbgw", "trace", "--count", "1",
                              "--control", gw.control], stdout=subprocess.PIPE, text=True)
    try:
        assert "FRAME" in trace.stdout.readline()         # subscribed: the column header
        device.send(b"ok\r")
        assert trace.stdout.readline().split()[1:] == ["rx", "3", "stored", "6f6b0d"]
    finally:
        trace.kill()
        trace.wait()
    counters(gw, frames_stored=1)
    text = urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics",
                                  timeout=REPLY_S).read().decode()
    families = metric_families(prometheus_client.parser, text)
    assert metric_value(families, "mbgw_transparent_frames_stored",
                        "mbgw_transparent_frames_stored_total") == 1
    assert metric_value(families, "mbgw_line_up") == 1


def test_trace_raw_says_transparent_mode_shows_frames_in_hex_instead(transparent):
    gw, _, _ = transparent("--eof", "cr")
    done = mbgw("trace", "--raw", "--control", gw.control)
    assert done.returncode == 1, done
    assert done.stderr.strip() == "mbgw: --raw: transparent mode has no raw line view; mbgw " \
        "trace shows each frame there in hex as it went on the line", done.stderr


def test_reload_applies_new_frame_settings(transparent, tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text('[transparent]\neof = "cr"\nrx-size = 8\n')
    gw, device, client = transparent("--config", str(path))
    device.send(b"a\r")
    counters(gw, frames_stored=1)
    path.write_text('[transparent]\neof = "lf"\nrx-size = 8\n')
    gw.proc.send_signal(signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: transparent changed")
    device.send(b"b\rc\n")
    counters(gw, frames_stored=2)
    assert read_area(client, RX, 8) == registers(b"b\rc\n", 8)


def test_the_table_servers_max_connections_and_its_reload(transparent, tmp_path):
    """[table] max-connections caps mdbport's clients in transparent mode too (a third
    polling client is closed at once, naming the key); a reload raises it for the next."""
    path = tmp_path / "mbgw.toml"
    path.write_text("[table]\nmax-connections = 2\n")
    gw, device, client = transparent("--config", str(path))
    second = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S)
    try:
        for polling in (client, second):
            assert polling.connect()
            read_area(polling, RX, 2)           # both have asked: neither makes room
        extra = socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_S,
                                         source_address=("127.0.0.2", 0))
        with extra:
            assert extra.recv(16) == b""
        tcp = status(gw)["table"]["tcp"]
        assert (tcp["max_connections"], tcp["connections_refused_limit"]) == (2, 1)
        assert "(table.max-connections)" in gw.log()
        path.write_text("[table]\nmax-connections = 3\n")
        gw.proc.send_signal(signal.SIGHUP)
        wait_for_log(gw, "configuration reloaded")
        third = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S,
                                source_address=("127.0.0.2", 0))
        try:
            assert third.connect()
            read_area(third, RX, 2)
        finally:
            third.close()
        assert status(gw)["table"]["tcp"]["max_connections"] == 3
    finally:
        second.close()


def test_a_reload_of_authip_closes_the_table_clients_it_no_longer_allows(transparent,
                                                                         tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text('[serial]\nmode = "transparent"\n[net]\nauthip = ["127.0.0.1"]\n')
    gw, device, client = transparent("--config", str(path))
    read_area(client, RX, 2)
    refused = socket.create_connection(("127.0.0.1", gw.port), timeout=REPLY_S,
                                       source_address=("127.0.0.2", 0))
    with refused:
        assert refused.recv(16) == b""
    path.write_text('[serial]\nmode = "transparent"\n[net]\nauthip = ["127.0.0.2"]\n')
    gw.proc.send_signal(signal.SIGHUP)
    wait_for_log(gw, "no longer allowed by authip")
    with pytest.raises(ConnectionException, match="closed"):        # its connection ended
        client.read_holding_registers(RX, count=1)
    allowed = ModbusTcpClient("127.0.0.1", port=gw.port, timeout=REPLY_S,
                              source_address=("127.0.0.2", 0))
    try:
        assert allowed.connect()
        read_area(allowed, RX, 2)
    finally:
        allowed.close()


def test_the_table_clients_are_listed_and_closed_by_the_operator(transparent):
    """mbgw clients lists mdbport's clients beside the raw port; clients close ends one."""
    gw, device, client = transparent()
    read_area(client, RX, 2)
    listed = wait_for(gw, lambda s: len(s["clients"]) == 1 and s["clients"][0]["requests"],
                      "the client listed")["clients"]
    text = mbgw("clients", "--control", gw.control).stdout
    assert text.startswith("table clients (1)") and listed[0]["peer"] in text, text
    assert "raw        off" in text
    assert "table clients (1)" in mbgw("status", "--control", gw.control).stdout
    result = mbgw("clients", "close", listed[0]["peer"], "--control", gw.control)
    assert result.returncode == 0, result.stderr
    with pytest.raises(ConnectionException, match="closed"):        # its connection ended
        client.read_holding_registers(RX, count=1)
    assert f"table client {listed[0]['peer']} closed by the operator" in gw.log()
