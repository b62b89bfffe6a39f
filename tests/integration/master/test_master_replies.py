"""Master mode: a server's reply that carries the request's transaction id but does not answer
the request (another unit id, function or size, a bad MBAP header) never reaches the line.

The server is scripted here: a raw Modbus TCP server in a thread of the test, on a loopback
address, that answers reads of holding registers correctly (register i of unit u holds
u << 8 | i) unless the test has queued a fault for the next request; it records the requests
and connections it sees.  The serial master is the test, writing raw RTU frames on a socat
pty (tests.modbus builds them, with its own CRC).  Each bad reply must give 0x0B (with
--exception) or nothing, be counted by its kind, and leave the next request served.
"""
import collections
import os
import re
import selectors
import socket
import struct
import threading
import time

import pytest

from tests.harness import free_port
from tests.integration.master.rig import (
    ask,
    holding_reply,
    read_holding,
    rtu,
    stop_counters,
    wait_for,
)
from tests.ops import devices, health_log, tracing

pytestmark = pytest.mark.integration

HOST = "127.0.8.6"
ADDRESS = 6                   # the serial address, sent upstream as unit 6
UNIT = 6
OTHER_UNIT = 0x46
TCPTO_MS = 5000               # far above ask()'s wait: a bad reply must end the wait at once
COUNT = 3                     # registers read by each request


def registers(unit: int, start: int, count: int) -> bytes:
    return b"".join(struct.pack(">H", (unit << 8 | start + i) & 0xFFFF) for i in range(count))


def read_reply(unit: int, start: int, count: int, function: int = 0x03) -> bytes:
    data = registers(unit, start, count)
    return bytes((function, len(data))) + data


def mbap(tid: int, unit: int, pdu: bytes, protocol: int = 0, length: int | None = None) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1 if length is None else length,
                       unit) + pdu


# What the server sends for a read of `count` registers from `start` of `unit` (tid, unit,
# start, count -> the bytes on the wire), and the counters that must tell it:
# (the device's counter, the line-wide counter).
FAULTS = {
    "wrong-unit": (lambda t, u, s, n: mbap(t, OTHER_UNIT, read_reply(OTHER_UNIT, s, n)),
                   ("wrong_unit", "wrong_unit")),
    "wrong-function": (lambda t, u, s, n: mbap(t, u, read_reply(u, s, n, function=0x04)),
                       ("wrong_function", "wrong_function")),
    "another-functions-exception": (lambda t, u, s, n: mbap(t, u, bytes.fromhex("84 02")),
                                    ("wrong_function", "wrong_function")),
    "wrong-size": (lambda t, u, s, n: mbap(t, u, read_reply(u, s, n - 1)),
                   ("wrong_function", "wrong_function")),
    "protocol-id": (lambda t, u, s, n: mbap(t, u, read_reply(u, s, n), protocol=1),
                    ("invalid_frames", "connections_bad_header")),
    # the MBAP length counts two bytes more than the PDU, and they follow it
    "length-longer": (lambda t, u, s, n: mbap(t, u, read_reply(u, s, n) + b"\0\0"),
                      ("invalid_frames", "connections_bad_header")),
    # the MBAP length counts two bytes less than the PDU that follows it
    "length-shorter": (lambda t, u, s, n: mbap(t, u, read_reply(u, s, n),
                                               length=len(read_reply(u, s, n)) - 1),
                       ("invalid_frames", "connections_bad_header")),
}
CLOSES_CONNECTION = {"protocol-id", "length-longer", "length-shorter"}


class ScriptedServer:
    """A Modbus TCP server on (host, port), in a thread; `faults` holds what the next replies
    become (a FAULTS function each; b"" is no reply), the correct reply when empty; `delays`
    how long the next replies wait (s; sent by a timer meanwhile, the server reading on),
    none when empty; `sent` is (tid, time.monotonic()) for each reply sent."""

    def __init__(self, host: str, port: int) -> None:
        self.faults = collections.deque()
        self.delays: collections.deque[float] = collections.deque()
        self.sent: list[tuple[int, float]] = []
        self._send_lock = threading.Lock()
        self.requests: list[tuple[int, int, bytes]] = []      # (tid, unit, PDU)
        self.arrivals: list[float] = []                       # time.monotonic() of each
        self.connections = 0
        self.port = port
        self._listener = socket.create_server((host, port))
        self._wake_r, self._wake_w = socket.socketpair()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._wake_w.send(b"x")
        self._thread.join(5)
        for s in (self._listener, self._wake_r, self._wake_w):
            s.close()

    def _serve(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._listener, selectors.EVENT_READ)
        sel.register(self._wake_r, selectors.EVENT_READ)
        buffers: dict[socket.socket, bytearray] = {}
        while True:
            for key, _ in sel.select():
                sock = key.fileobj
                if sock is self._wake_r:
                    for conn in buffers:
                        conn.close()
                    sel.close()
                    return
                if sock is self._listener:
                    conn, _ = sock.accept()
                    self.connections += 1
                    buffers[conn] = bytearray()
                    sel.register(conn, selectors.EVENT_READ)
                    continue
                data = sock.recv(4096)
                if not data:
                    sel.unregister(sock)
                    del buffers[sock]
                    sock.close()
                    continue
                buf = buffers[sock]
                buf += data
                while len(buf) >= 7 and len(buf) >= 6 + (length := buf[4] << 8 | buf[5]):
                    tid, unit, pdu = buf[0] << 8 | buf[1], buf[6], bytes(buf[7:6 + length])
                    del buf[:6 + length]
                    self.arrivals.append(time.monotonic())
                    self.requests.append((tid, unit, pdu))
                    reply = self._reply(tid, unit, pdu)
                    delay = self.delays.popleft() if self.delays else 0
                    if delay:
                        threading.Timer(delay, self._send, (sock, tid, reply)).start()
                    else:
                        self._send(sock, tid, reply)

    def _send(self, sock: socket.socket, tid: int, reply: bytes) -> None:
        with self._send_lock:
            try:
                sock.sendall(reply)
            except OSError:         # closed meanwhile (the test is over)
                return
            self.sent.append((tid, time.monotonic()))

    def _reply(self, tid: int, unit: int, pdu: bytes) -> bytes:
        function, start, count = struct.unpack(">BHH", pdu)
        assert function == 0x03, pdu.hex(" ")
        if self.faults:
            return self.faults.popleft()(tid, unit, start, count)
        return mbap(tid, unit, read_reply(unit, start, count))


@pytest.fixture
def server():
    scripted = ScriptedServer(HOST, free_port())
    yield scripted
    scripted.stop()


@pytest.fixture
def gateway(server, start_master):
    """gateway(*options) -> `mbgw master` with address 6 -> HOST unit 6, tcpto TCPTO_MS."""
    def start(*options: str):
        return start_master("--mdbport", str(server.port),
                            "--slaveid", f"{ADDRESS} {ADDRESS} {UNIT} 0 {HOST}",
                            "--tcpto", str(TCPTO_MS), *options)
    return start


def good_reply() -> bytes:
    return holding_reply(ADDRESS, *struct.unpack(f">{COUNT}H", registers(UNIT, 0, COUNT)))


def bad_reply_warnings(gw) -> list[str]:
    return [text for text in gw.log().splitlines()
            if " WARNING " in text and "does not answer the request" in text]


def over(d: dict) -> bool:
    """The device's transactions have all ended (answered or failed), whichever way."""
    return d["transactions"] == d["replies"] + d["consecutive_failures"]


@pytest.mark.parametrize("exception", [True, False], ids=["exception", "silence"])
@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_reply_that_does_not_answer_never_reaches_the_line(gateway, server, line, fault,
                                                             exception):
    make, (device_counter, line_counter) = FAULTS[fault]
    gw = gateway(*(["--exception"] if exception else []))
    server.faults.append(make)
    request = read_holding(ADDRESS, count=COUNT)
    if exception:
        ask(line, request, expected=bytes.fromhex("06 83 0b"))
    else:
        os.write(line, rtu(request))
        wait_for(gw, lambda s: ADDRESS in devices(s) and over(devices(s)[ADDRESS]),
                 "ended the transaction")
    # nothing else came: the next frame on the line is the answer to the next request
    ask(line, request, expected=good_reply())
    assert [(unit, pdu) for _, unit, pdu in server.requests] == [(UNIT, request[1:])] * 2
    assert server.connections == (2 if fault in CLOSES_CONNECTION else 1)

    d = devices(wait_for(gw, lambda s: devices(s)[ADDRESS]["replies"] == 1,
                         "counted the reply"))[ADDRESS]
    assert {k: d[k] for k in ("transactions", "replies", "timeouts", device_counter)} == {
        "transactions": 2, "replies": 1, "timeouts": 0, device_counter: 1}
    assert d["gateway_exceptions"] == ({"0x0b": 1} if exception else {})
    assert d["health"] == "degraded" and d["exceptions"] == {}
    assert len(bad_reply_warnings(gw)) == 1, gw.log()
    c = stop_counters(gw)
    assert (c[line_counter], c["timeouts"], c["replies"]) == (1, 0, 1 + exception)
    assert c["gateway_exceptions"] == exception
    others = {"wrong_unit", "wrong_function", "connections_bad_header", "connections_lost",
              "late_replies", "abandoned"} - {line_counter}
    assert {name: c[name] for name in others} == dict.fromkeys(others, 0)


def test_a_server_that_keeps_answering_for_another_unit_is_logged_once_and_goes_down(
        gateway, server, line):
    gw = gateway("--exception", "--probe-interval", "100")
    for _ in range(3):
        server.faults.append(FAULTS["wrong-unit"][0])
        ask(line, read_holding(ADDRESS, count=COUNT), expected=bytes.fromhex("06 83 0b"))
    d = devices(wait_for(gw, lambda s: devices(s)[ADDRESS]["wrong_unit"] == 3,
                         "counted three bad replies"))[ADDRESS]
    assert (d["health"], d["consecutive_failures"]) == ("down", 3)
    assert health_log(gw, ADDRESS) == ["degraded", "down"]
    port = server.port
    assert [re.sub(r"^.*WARNING ", "", w) for w in bad_reply_warnings(gw)] == [
        f"mbgw.line: device 6: the reply of server {HOST}:{port} unit 6 does not answer the "
        f"request (unit id 70 instead of 6): dropped (replies of this kind for this address "
        f"are logged at most once a minute)"]
    # another kind is logged too, when the probe of the address that is down meets it
    server.faults.append(FAULTS["wrong-size"][0])
    while len(server.requests) == 3:
        ask(line, read_holding(ADDRESS, count=COUNT), expected=bytes.fromhex("06 83 0b"))
    assert len(server.requests) == 4 and not server.faults
    assert len(bad_reply_warnings(gw)) == 2, gw.log()
    assert "(a function 0x03 PDU of 6 bytes, not the size or echo the request asks for)" \
        in gw.log()


def test_the_trace_shows_the_servers_reply_and_what_became_of_it(gateway, server, line,
                                                                 tmp_path):
    gw = gateway("--exception")
    with tracing(gw, tmp_path / "trace.pcap", count=2) as (trace, _):
        server.faults.append(FAULTS["wrong-unit"][0])
        ask(line, read_holding(ADDRESS, count=COUNT), expected=bytes.fromhex("06 83 0b"))
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    events = [text.split(None, 8)[1:] for text in out.decode().splitlines()]
    server_name = f"{HOST}:{server.port}"
    assert events[0] == ["request", "6", server_name, "1", "6", "0x03", "5"]
    assert events[1][:7] == ["reply", "6", server_name, "1", str(OTHER_UNIT), "0x03", "8"]
    assert re.fullmatch(r"not the answer: unit id 70 instead of 6, answered 0x0b [\d.]+ ms",
                        events[1][7]), events[1]


def test_a_late_reply_is_dropped_by_its_transaction_id_while_the_next_request_waits(
        gateway, server, line, tmp_path):
    """The server answers A (2 registers at 0) 300 ms after it came, tcpto being 200 ms; the
    master gets 0x0B and asks B (2 registers at 50: a reply of the same size), which the
    server answers 150 ms after it came.  A's late reply arrives on the connection while B
    waits: it carries A's transaction id, so it is dropped, counted and traced, and the
    master gets B's own registers."""
    gw = gateway("--exception", "--tcpto", "200")
    server.delays.extend((0.3, 0.15))
    with tracing(gw, tmp_path / "trace.pcap", count=5) as (trace, _):
        ask(line, read_holding(ADDRESS, start=0, count=2), expected=bytes.fromhex("06 83 0b"))
        ask(line, read_holding(ADDRESS, start=50, count=2),
            expected=holding_reply(ADDRESS, *struct.unpack(">2H", registers(UNIT, 50, 2))))
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    (tid_a, _, _), (tid_b, _, _) = server.requests
    assert tid_a != tid_b
    assert [tid for tid, _ in server.sent] == [tid_a, tid_b]
    assert server.arrivals[1] < server.sent[0][1]          # A's late reply came while B waited
    events = [text.split(None, 8)[1:] for text in out.decode().splitlines()]
    server_name = f"{HOST}:{server.port}"
    assert [e[0] for e in events] == ["request", "no", "request", "late", "reply"]   # no reply
    assert events[3] == ["late", str(ADDRESS), server_name, str(tid_a), str(UNIT), "0x03", "6",
                         "late reply, dropped"]
    c = stop_counters(gw)
    assert (c["late_replies"], c["timeouts"], c["replies"]) == (1, 1, 2)
