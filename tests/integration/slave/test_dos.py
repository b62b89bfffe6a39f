"""Slave mode under denial-of-service attempts: connections that dribble a request, that say
nothing, that pipeline far more than the gateway holds for a client.  The serial side is
pymodbus 3.16.1's RTU server on a socat pty (tests/peers/pymodbus_slave.py, slave 17)."""
import json
import os
import socket
import threading
import time

import pytest

from mbgw.ops import control
from mbgw.ops.metrics_server import PER_ADDRESS
from tests import harness
from tests.integration.slave.test_connections import (
    READ_3,
    REPLY_3,
    assert_closed,
    assert_served,
)
from tests.modbus import mbap as adu
from tests.modbus import recv_adu
from tests.ops import wait_for, wait_for_log

pytestmark = pytest.mark.integration

SERVED_WITHIN_S = 2.0         # a legitimate newcomer beside a slowloris: a functional bound


@pytest.fixture
def rtu(pty_pair, start_peer):
    start_peer("pymodbus_slave.py", pty_pair.device, "17", "--silent-unknown")
    return pty_pair


class Dribbler(threading.Thread):
    """Sends the next byte of a request on every connection, one a second, until stopped."""

    def __init__(self, connections: list[socket.socket]) -> None:
        super().__init__(daemon=True)
        self.connections = connections
        self.stopping = threading.Event()

    def run(self) -> None:
        request = adu(1, 17, READ_3)
        for byte in range(len(request)):
            for sock in self.connections:
                try:
                    sock.send(request[byte:byte + 1])
                except OSError:
                    pass                # closed by the gateway: that is its right
            if self.stopping.wait(1.0):
                return


def test_a_slowloris_does_not_lock_a_newcomer_out(rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200")      # max-connections 5
    slow = [sockets.connect(gw.port) for _ in range(50)]
    dribbler = Dribbler(slow)
    dribbler.start()
    try:
        time.sleep(1.5)         # the attack under way: every slot holds a dribbler
        newcomer = sockets.connect(gw.port)
        newcomer.settimeout(SERVED_WITHIN_S)
        started = time.monotonic()
        assert_served(newcomer)
        assert time.monotonic() - started < SERVED_WITHIN_S
        assert_served(newcomer, tid=2)      # and it stays: it is polling
    finally:
        dribbler.stopping.set()
        dribbler.join()


def test_a_request_not_whole_within_request_timeout_closes_its_connection(
        rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--request-timeout", "300")
    poller = sockets.connect(gw.port)
    assert_served(poller)
    dribbler = sockets.connect(gw.port)
    dribbler.sendall(adu(1, 17, READ_3)[:7])
    assert_closed(dribbler, within=3.0)
    s = wait_for(gw, lambda s: s["counters"]["connections_timed_out"] == 1, "counted")
    assert len(s["clients"]) == 1
    assert_served(poller, tid=2)
    assert "a request not whole within request-timeout (300 ms)" in gw.log()


@pytest.mark.serial
def test_pipelined_requests_beyond_sixteen_wait_in_the_socket(rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200")
    sock = sockets.connect(gw.port)
    count = 340
    sock.sendall(b"".join(adu(tid, 17, READ_3) for tid in range(count)))
    in_flight = []

    def watch() -> None:
        while len(in_flight) < 2000:
            s = wait_for(gw, lambda s: True, "status")
            in_flight.extend(c["in_flight"] for c in s["clients"])
            if s["counters"]["replies"] >= count:
                return
    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    for tid in range(count):        # every one answered, in order, on the wire
        assert recv_adu(sock, 5.0) == adu(tid, 17, REPLY_3)
    watcher.join(10)
    assert in_flight and max(in_flight) <= 16


def threads(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/task"))


def rss_kib(pid: int) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def test_idle_metrics_connections_are_capped_and_another_address_is_scraped(
        rtu, start_gateway, sockets):
    port = harness.free_port()
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--metrics", f"127.0.0.1:{port}")
    before = threads(gw.proc.pid)
    idle = [sockets.connect(port) for _ in range(40)]       # never send a request
    for sock in idle[PER_ADDRESS:PER_ADDRESS + 5]:
        assert_closed(sock, within=3.0)                     # over the address's share
    assert threads(gw.proc.pid) <= before + PER_ADDRESS
    scrape = sockets.connect(port, source="127.0.0.2")
    scrape.sendall(b"GET /metrics HTTP/1.0\r\n\r\n")
    assert scrape.recv(100).startswith(b"HTTP/1.0 200 ")


def test_what_a_trace_client_sends_is_dropped_not_kept(rtu, start_gateway):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200")
    trace = control.connect(gw.control)
    trace.sendall(b'{"command": "trace"}\n')
    assert json.loads(trace.makefile().readline())       # the header: the trace runs
    before = rss_kib(gw.proc.pid)
    junk = b"x" * 65536
    for _ in range(320):                                  # 20 MiB the daemon must not keep
        trace.sendall(junk)
    wait_for(gw, lambda s: True, "status after the junk")
    assert rss_kib(gw.proc.pid) - before < 8 * 1024
    trace.close()
    wait_for_log(gw, "trace ended")


def fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


@pytest.mark.usefixtures("many_fds")
def test_connect_close_cycles_and_half_open_connections_leave_nothing_behind(
        rtu, start_gateway, sockets):
    gw = start_gateway(rtu.gateway, "--baudrate", "19200", "--request-timeout", "500")
    poller = sockets.connect(gw.port)
    assert_served(poller)
    pid = gw.proc.pid
    fds_before, rss_before = fds(pid), rss_kib(pid)
    for n in range(5000):
        sock = socket.create_connection(("127.0.0.1", gw.port))
        if n % 2:
            sock.sendall(adu(n, 17, READ_3)[:5])       # a request begun, never ended
        sock.close()
    half_open = []
    for _ in range(1000):                               # begun and left: no FIN, no more bytes
        sock = socket.socket()
        sock.setblocking(False)
        try:
            sock.connect(("127.0.0.1", gw.port))
        except BlockingIOError:
            pass
        half_open.append(sock)
    try:
        assert_served(poller, tid=2)                    # the line's client is served meanwhile
        # once the newcomers are all taken in, the limit's worth at most (and the status's)
        wait_for(gw, lambda s: fds(pid) <= fds_before + 5 + 1, "the descriptors settled")
        assert rss_kib(pid) - rss_before < 8 * 1024
    finally:
        for sock in half_open:
            sock.close()
    wait_for(gw, lambda s: [c["peer"] for c in s["clients"]] ==
             ["127.0.0.1:%d" % poller.getsockname()[1]], "the poller alone again")
    wait_for(gw, lambda s: fds(pid) <= fds_before + 1, "the descriptors back")
    assert_served(poller, tid=3)
