"""Slave mode's TCP side: connection limits, authip, bad MBAP headers, readiness, the command
line.

The serial side is pymodbus 3.16.1's RTU server on a socat pty (tests/peers/pymodbus_slave.py,
slave 17: holding register n holds 100 + n).
"""
import itertools
import signal
import socket
import struct
import subprocess
import sys
import threading

import pytest

from tests import harness
from tests.modbus import holding_reply, recv_adu
from tests.modbus import mbap as adu
from tests.ops import wait_for
from tests.wait import until

pytestmark = pytest.mark.integration

REPLY_TIMEOUT_S = 3.0
CLOSED_WITHIN_S = 0.5     # a refused or evicted connection must see EOF/reset within this


READ_3 = bytes.fromhex("03 0000 0003")
REPLY_3 = bytes.fromhex("03 06 0064 0065 0066")     # 100, 101, 102


def assert_served(sock: socket.socket, tid: int = 0x0101, unit: int = 17) -> None:
    sock.sendall(adu(tid, unit, READ_3))
    assert recv_adu(sock) == adu(tid, unit, REPLY_3)


def assert_closed(sock: socket.socket, within: float = CLOSED_WITHIN_S) -> None:
    """The gateway closed sock without sending anything: EOF or reset, and soon."""
    sock.settimeout(within)
    try:
        data = sock.recv(1024)
    except ConnectionResetError:
        return
    except socket.timeout:
        pytest.fail(f"connection still open after {within} s")
    assert data == b"", f"the gateway answered: {data.hex(' ')}"


def reset(sock: socket.socket) -> None:
    """Close sock with a reset (SO_LINGER 0) instead of a FIN."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


def connect(port: int, source: str | None = None) -> socket.socket:
    sock = socket.socket()
    sock.settimeout(REPLY_TIMEOUT_S)
    if source:
        sock.bind((source, 0))
    sock.connect(("127.0.0.1", port))
    return sock


class Sockets(list):
    """Sockets to close after the test."""

    def connect(self, port: int, source: str | None = None) -> socket.socket:
        """A new connection to port, closed after the test."""
        self.append(connect(port, source))
        return self[-1]


@pytest.fixture
def rtu(pty_pair, start_peer):
    """pymodbus slave 17 on the line; requests to any other address get no reply."""
    start_peer("pymodbus_slave.py", pty_pair.device, "17", "--silent-unknown")
    return pty_pair


# ---- --max-connections ----

def test_newcomer_closes_a_connection_that_never_sent_a_request(rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--max-connections", "2")
    poller = sockets.connect(gw.port)
    assert_served(poller)
    silent = sockets.connect(gw.port)       # more recently active than the poller, but silent
    newcomer = sockets.connect(gw.port)
    assert_served(newcomer)
    assert_closed(silent)
    assert_served(poller, tid=2)
    assert "closed to make room" in gw.log()


def test_a_newcomer_cannot_close_a_polling_client(rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--max-connections", "1")
    poller = sockets.connect(gw.port)
    assert_served(poller)
    assert_closed(sockets.connect(gw.port))
    assert_served(poller, tid=2)
    assert "all 1 connections of net.max-connections are busy" in gw.log()
    assert "closed to make room" not in gw.log()


def test_newcomer_refused_while_every_connection_has_a_request_in_flight(rtu, start_gateway,
                                                                         sockets):
    stout_s = 1.0
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--max-connections", "2",
                       "--exception", "--stout", str(int(stout_s * 1000)))
    first, second = connect(gw.port), connect(gw.port)
    sockets += [first, second]
    # Each connection sends, in one segment, a quick request then requests to absent unit 30
    # that each hold the line for stout.  Once the quick reply is back, the rest is queued.
    slow = bytes.fromhex("03 0000 0001")
    first.sendall(adu(1, 17, READ_3) + adu(2, 30, slow) + adu(3, 30, slow))
    second.sendall(adu(1, 17, READ_3) + adu(2, 30, slow))
    assert recv_adu(first) == adu(1, 17, REPLY_3)
    assert recv_adu(second) == adu(1, 17, REPLY_3)
    # Both have requests in flight for at least another stout: the newcomer is refused.
    assert_closed(sockets.connect(gw.port))
    # ... and the busy connections were left alone: each gets its 0x0B (no reply) answers.
    timeout = 3 * stout_s + REPLY_TIMEOUT_S
    assert recv_adu(first, timeout) == adu(2, 30, bytes.fromhex("83 0b"))
    assert recv_adu(second, timeout) == adu(2, 30, bytes.fromhex("83 0b"))
    assert recv_adu(first, timeout) == adu(3, 30, bytes.fromhex("83 0b"))
    assert "connections are busy" in gw.log()


def settled(gw, sock: socket.socket, unit: int = 17, reply: bytes = REPLY_3) -> None:
    """sock, adopted and served once, and the gateway's books kept: the line thread is
    asleep with the line idle, where the next request meets the idle line's shortcut."""
    sock.sendall(adu(9, unit, READ_3))
    assert recv_adu(sock) == adu(9, unit, reply)
    wait_for(gw, lambda s: s["counters"]["replies"] == 1, "kept the books of the reply")


def test_a_connection_is_idle_again_once_its_pipelined_requests_are_answered(
        rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--max-connections", "1")
    first = sockets.connect(gw.port)
    settled(gw, first)
    # two requests in one segment: the shortcut leaves them to the queue
    first.sendall(adu(1, 17, READ_3) + adu(2, 17, READ_3))
    assert recv_adu(first) == adu(1, 17, REPLY_3)
    assert recv_adu(first) == adu(2, 17, REPLY_3)
    # (a newcomer cannot show it: the connection has been active within the minute)
    wait_for(gw, lambda s: [c["in_flight"] for c in s["clients"]] == [0], "idle again")


def test_a_lone_request_on_the_line_keeps_its_connection_from_eviction(
        pty_pair, recording_peer, start_gateway, sockets):
    record = recording_peer("fault_slave.py")           # address 2 never answers
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--max-connections", "1",
                       "--exception", "--stout", "1000")
    first = sockets.connect(gw.port)
    settled(gw, first, unit=1, reply=holding_reply(0, 3))
    first.sendall(adu(1, 2, READ_3))                    # taken by the shortcut
    wait_for_record(record, "rx 02 03")                   # on the line, stout to go
    assert_closed(sockets.connect(gw.port))
    assert recv_adu(first) == adu(1, 2, bytes.fromhex("83 0b"))
    assert "connections are busy" in gw.log()


def wait_for_record(record, text: str) -> None:
    """Until the scripted slave has recorded a frame starting with text."""
    until(lambda: record.exists() and text in record.read_text(),
          f"the slave recording {text!r}", REPLY_TIMEOUT_S)


SLOW = bytes.fromhex("03 0000 0001")           # to address 2, which never answers
NO_REPLY = bytes.fromhex("83 0b")


@pytest.mark.parametrize("end", [socket.socket.close, reset], ids=["close", "reset"])
def test_a_connection_its_peer_has_ended_does_not_count(pty_pair, recording_peer,
                                                        start_gateway, sockets, end):
    record = recording_peer("fault_slave.py")
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--max-connections", "2",
                       "--exception", "--stout", "1000")
    first, second = sockets.connect(gw.port), sockets.connect(gw.port)
    settled(gw, first, unit=1, reply=holding_reply(0, 3))
    second.sendall(adu(9, 1, READ_3))
    assert recv_adu(second) == adu(9, 1, holding_reply(0, 3))
    first.sendall(adu(1, 2, SLOW))
    wait_for_record(record, "rx 02 03")     # the line thread waits for stout, reads nobody
    end(second)                             # both were active just now: neither may be closed
    newcomer = sockets.connect(gw.port)     # ... but second is gone: there is room
    newcomer.sendall(adu(2, 1, READ_3))
    assert recv_adu(first) == adu(1, 2, NO_REPLY)
    assert recv_adu(newcomer) == adu(2, 1, holding_reply(0, 3))
    assert "refused" not in gw.log() and "closed to make room" not in gw.log()


def test_a_first_request_not_read_yet_keeps_its_connection(pty_pair, recording_peer,
                                                           start_gateway, sockets):
    record = recording_peer("fault_slave.py")
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--max-connections", "2",
                       "--exception", "--stout", "1000")
    first = sockets.connect(gw.port)
    settled(gw, first, unit=1, reply=holding_reply(0, 3))
    first.sendall(adu(1, 2, SLOW))
    wait_for_record(record, "rx 02 03")     # the line thread waits for stout, reads nobody
    second = sockets.connect(gw.port)
    second.sendall(adu(2, 1, READ_3))       # its first request, in the gateway's socket
    assert_closed(sockets.connect(gw.port))
    assert recv_adu(first) == adu(1, 2, NO_REPLY)
    assert recv_adu(second) == adu(2, 1, holding_reply(0, 3))
    assert "closed to make room" not in gw.log()


CHURNS = 300
CHURNERS = 4          # each holds at most one connection: at most 4 others open at once
PARTIAL_HEADER = adu(1, 17, READ_3)[:3]


def churn(port: int, kind: int) -> None:
    """One connection that comes and goes: connect + close, part of a header + close, or
    connect + reset."""
    sock = socket.socket()
    try:
        sock.connect(("127.0.0.1", port))
        if kind == 1:
            sock.sendall(PARTIAL_HEADER)
        elif kind == 2:
            reset(sock)
    except OSError:
        pass                              # refused meanwhile: it is gone too
    finally:
        sock.close()


def test_a_polling_client_outlives_connections_that_come_and_go(rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--max-connections", "5")
    poller = sockets.connect(gw.port)
    assert_served(poller)
    numbers = itertools.count()
    lock = threading.Lock()

    def churner() -> None:
        while True:
            with lock:
                n = next(numbers)
            if n >= CHURNS:
                return
            churn(gw.port, n % 3)

    threads = [threading.Thread(target=churner) for _ in range(CHURNERS)]
    for thread in threads:
        thread.start()
    polls = 0
    try:
        while any(thread.is_alive() for thread in threads):
            polls += 1
            assert_served(poller, tid=polls & 0xFFFF)
    finally:
        for thread in threads:
            thread.join()
    poller_address = "127.0.0.1:%d" % poller.getsockname()[1]
    assert f"client {poller_address} closed" not in gw.log()


# ---- --max-connections-per-ip ----

def test_one_address_over_its_limit_is_refused_and_another_gets_in(rtu, start_gateway,
                                                                    sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--max-connections-per-ip", "2")
    first, second = sockets.connect(gw.port), sockets.connect(gw.port)
    assert_closed(sockets.connect(gw.port))
    other = sockets.connect(gw.port, source="127.0.0.2")
    assert_served(other)
    assert_served(first)
    assert_served(second)
    reset(first)                            # gone: its address has room again
    assert_served(sockets.connect(gw.port))
    refusals = [line for line in gw.log().splitlines() if "refused" in line]
    assert len(refusals) == 1 and "127.0.0.1" in refusals[0], refusals
    assert "max-connections-per-ip" in refusals[0]
    assert "closed to make room" not in gw.log()


# ---- --authip ----

def test_authip_refuses_other_addresses_and_logs_it_once(rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--authip", "127.0.0.2")
    stranger = connect(gw.port)           # from 127.0.0.1
    sockets.append(stranger)
    try:
        stranger.sendall(adu(1, 17, READ_3))
    except (BrokenPipeError, ConnectionResetError):
        pass                              # already closed: fine
    assert_closed(stranger)

    friend = connect(gw.port, source="127.0.0.2")
    sockets.append(friend)
    assert_served(friend)

    for _ in range(20):
        again = connect(gw.port)
        sockets.append(again)
        assert_closed(again)              # once closed, the gateway has logged (or not) already
    assert_served(friend, tid=2)
    refusals = [line for line in gw.log().splitlines() if "refused" in line]
    assert len(refusals) == 1, refusals
    assert "127.0.0.1" in refusals[0] and "authip" in refusals[0]


# ---- bad MBAP headers ----

BAD_HEADERS = {
    "protocol-1": struct.pack(">HHHB", 7, 1, 6, 17) + READ_3,
    "length-0": struct.pack(">HHHB", 7, 0, 0, 17) + READ_3,
    "length-300": struct.pack(">HHHB", 7, 0, 300, 17) + READ_3,
}


@pytest.mark.parametrize("frame", BAD_HEADERS.values(), ids=BAD_HEADERS.keys())
def test_bad_mbap_header_closes_that_connection_only(rtu, start_gateway, sockets, frame):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200")
    good, bad = connect(gw.port), connect(gw.port)
    sockets += [good, bad]
    assert_served(good)
    assert_served(bad)
    bad.sendall(frame)
    assert_closed(bad)
    assert_served(good, tid=2)
    assert "bad MBAP header" in gw.log()


# ---- readiness and the command line ----

def test_ready_means_one_info_line_naming_address_and_device(rtu, start_gateway):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200")
    lines = gw.log().splitlines()       # as it stands when READY=1 arrived
    address = f"127.0.0.1:{gw.port}"
    naming = [line for line in lines if address in line]
    assert len(naming) == 1, lines
    assert " INFO " in naming[0] and rtu.gateway in naming[0], naming[0]
    assert not [line for line in lines if " WARNING " in line or " ERROR " in line], lines
    with connect(gw.port) as sock:
        assert_served(sock)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mbgw", "slave", *args],
                          capture_output=True, text=True, timeout=10)


BAD_OPTIONS = {
    "baudrate": ("--baudrate", "49"),
    "protocol": ("--protocol", "tcp"),
    "interface": ("--interface", "rs485 loud"),
    "format": ("--format", "9x1"),
    "stout": ("--stout", "0"),
    "slaveid": ("--slaveid", "248"),
    "authip": ("--authip", "1.2.3"),
    "mdbport": ("--mdbport", "70000"),
    "max-connections": ("--max-connections", "0"),
    "max-connections-per-ip": ("--max-connections-per-ip", "-1"),
    "retries": ("--retries", "65536"),
    "log-level": ("--log-level", "chatty"),
}


@pytest.mark.parametrize("option, value", BAD_OPTIONS.values(), ids=BAD_OPTIONS.keys())
def test_bad_option_exits_2_naming_it(option, value):
    # /dev/null is no tty: were the option accepted, the gateway would exit 1, not hang
    out = run_cli("--device", "/dev/null", "--mdbport", "1502", option, value)
    assert out.returncode == 2, out.stderr
    assert f"'{option}'" in out.stderr, out.stderr
    assert out.stdout == ""


def test_a_device_that_does_not_open_exits_1_with_one_line():
    # there, but no tty (one that is not there is waited for: test_device_at_start.py)
    out = run_cli("--device", "/dev/zero", "--mdbport", str(harness.free_port()))
    assert out.returncode == 1, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "/dev/zero" in lines[0], out.stderr


def test_a_path_that_can_never_be_a_serial_device_exits_2_naming_it(tmp_path):
    regular = tmp_path / "ttyFILE"
    regular.write_text("")
    out = run_cli("--device", str(regular), "--mdbport", str(harness.free_port()))
    assert out.returncode == 2, out.stderr
    assert f"'--device': device {regular}: a regular file, not a serial device" in out.stderr


def test_sigterm_stops_cleanly_when_the_notify_socket_is_gone(rtu, start_gateway):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200")   # the harness closed its socket
    with connect(gw.port) as sock:
        assert_served(sock)   # the loop is past READY=1 and its signal handlers are in place
    gw.proc.send_signal(signal.SIGTERM)
    assert gw.proc.wait(10) == 0, gw.log()
    assert "stopped; counters:" in gw.log()
