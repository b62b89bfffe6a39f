"""Many lines in one slave-mode daemon (issue 24): the Modbus TCP face routes units to line
serial, to another line (with an offset) and to the exchange table; a unit no route takes is
refused; two clients on two lines in parallel each get their own replies only; one line lost
and back while the other keeps answering; a reload adding and removing a line; a remote
Modbus TCP server as a target.

Peers that are not ours: pymodbus RTU slaves on socat pty pairs (each recording what its line
carried), pymodbus TCP servers, raw sockets.  The lines and routes reach the daemon through
the configuration file's [[line]] and [[route]] tables.
"""
import json
import os
import select
import signal
import struct
import threading
from pathlib import Path

import pytest

from tests.harness import PtyPair, factory, free_port
from tests.integration.ops.test_reload import config_set
from tests.modbus import Client, mbap, read_holding
from tests.ops import mbgw, metric_value, scraped, status, wait_for, wait_for_log
from tests.wait import until

pytestmark = pytest.mark.integration

NO_REPLY_S = 0.5
SERIAL_SLAVE = 5          # on line serial
METER = 1                 # on line meters, reached as unit 32 (offset -31)
METER_UNIT = 32


def hr_reply(start: int, count: int) -> bytes:
    """The pymodbus slave's reply: holding register n holds 100 + n."""
    return bytes((0x03, 2 * count)) + b"".join(struct.pack(">H", 100 + start + i)
                                                for i in range(count))


def received(record: Path) -> list[bytes]:
    """What a recording pymodbus slave received: address + PDU, in order."""
    if not record.exists():
        return []
    return [bytes.fromhex(row.split()[2]) for row in record.read_text().splitlines()]


class Line:
    """A pty pair and a recording pymodbus slave on its device end."""

    def __init__(self, directory: Path, start_peer, *addresses: int) -> None:
        directory.mkdir(exist_ok=True)
        self.directory = directory
        self.pair = PtyPair(directory)
        self.record = directory / "record.txt"
        self.addresses = addresses
        self._start_peer = start_peer
        self.peer = start_peer("pymodbus_slave.py", self.pair.device,
                               *map(str, addresses), "--silent-unknown",
                               "--record", str(self.record))

    def lose(self) -> None:
        self.peer.stop()
        self.pair.stop()

    def restore(self) -> None:
        self.pair.start()
        self.peer = self._start_peer("pymodbus_slave.py", self.pair.device,
                                     *map(str, self.addresses), "--silent-unknown",
                                     "--record", str(self.record))

    def stop(self) -> None:
        self.pair.stop()


@pytest.fixture
def lines(tmp_path, start_peer):
    """lines(name, *addresses) -> a Line in tmp_path/name; stopped after the test."""
    yield from factory(lambda name, *addresses: Line(tmp_path / name, start_peer, *addresses),
                       Line.stop)


def lines_toml(spec: dict) -> str:
    """spec's lines and routes as the configuration file's [[line]] and [[route]] tables.
    spec: {"lines": [{"name", "device", "mode"?, "baudrate"?, "stout"?, "retries"?}],
           "routes": [{"units": "32-63", "line"? | "table"? | "server"? [host, port],
                       "offset"?, "address"?}]}"""
    text = []
    for line in spec.get("lines", ()):
        line = {"baudrate": 19200, "stout": 500, **line}
        text.append("[[line]]")
        text += [f"{key} = {json.dumps(value)}" for key, value in line.items()]
    for route in spec.get("routes", ()):
        text.append("[[route]]")
        for key, value in route.items():
            if key == "server":
                value = f"{value[0]}:{value[1]}"
            text.append(f"{key} = {json.dumps(value)}")
    return "\n".join(text) + "\n"


def write_lines(directory: Path, spec: dict) -> None:
    """The gateway's file (directory/mbgw.toml): what the test put in it before the gateway
    started, then spec's tables."""
    base = directory / "base.toml"
    (directory / "mbgw.toml").write_text(base.read_text() + lines_toml(spec))


@pytest.fixture
def gateway(tmp_path, start_gateway):
    """gateway(serial, spec, *options) -> mbgw slave on line serial's pty with the lines and
    routes of spec in its configuration file, tmp_path/mbgw.toml (kept with what the test
    wrote there before; write_lines changes them for a reload)."""
    def start(serial: Line, spec: dict, *options: str):
        path = tmp_path / "mbgw.toml"
        (tmp_path / "base.toml").write_text(path.read_text() if path.exists() else "")
        write_lines(tmp_path, spec)
        return start_gateway(serial.pair.gateway, "--config", str(path), "--baudrate", "19200",
                             "--stout", "300", *options)
    return start


def meters_spec(meters: Line, *routes: dict) -> dict:
    return {"lines": [{"name": "meters", "device": meters.pair.gateway, "stout": 300}],
            "routes": [{"units": "1-31", "line": "serial"},
                       {"units": "32-63", "line": "meters", "offset": -31}, *routes]}


def test_units_reach_their_line_rewritten_and_come_back_as_sent(lines, gateway, client):
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    gw = gateway(serial, meters_spec(meters), "--table", "--exception")
    c = client(gw)
    assert c.ask(SERIAL_SLAVE, read_holding(0, 2)) == hr_reply(0, 2)
    assert c.ask(METER_UNIT, read_holding(3, 4)) == hr_reply(3, 4)   # unit 32, not 1, back
    assert c.ask(250, read_holding(0, 1)) == bytes.fromhex("03 02 00 00")   # the table's
    assert c.ask(METER_UNIT + SERIAL_SLAVE - 1, read_holding(0, 1)) == b"\x83\x0b"  # none at 5
    assert received(serial.record) == [bytes((SERIAL_SLAVE,)) + read_holding(0, 2)]
    assert received(meters.record) == [bytes((METER,)) + read_holding(3, 4),
                                       bytes((SERIAL_SLAVE,)) + read_holding(0, 1)]
    s = status(gw)
    assert [(row["name"], row["state"]) for row in s["lines"]] == [("serial", "up"),
                                                                    ("meters", "up")]
    meters_row = s["lines"][1]
    assert (meters_row["requests"], meters_row["replies"], meters_row["timeouts"]) == (2, 2, 1)
    routes = {(r["units"], r["target"], r["rewrite"], r["implicit"]) for r in s["routes"]}
    assert routes == {("1-31", "line serial", "", False),
                      ("32-63", "line meters", "offset -31", False),
                      ("247-254", "table", "", True)}
    text = mbgw("status", "--control", gw.control).stdout
    assert "meters        up" in text and "32-63            line meters" in text, text


def test_a_unit_no_route_takes_reaches_no_line(lines, gateway, client):
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    gw = gateway(serial, meters_spec(meters), "--exception")
    c = client(gw)
    assert c.ask(100, read_holding(0, 1)) == b"\x83\x0a"
    assert c.ask(0x40, read_holding(0, 1)) == b"\x83\x0a"        # 64: just past the meters
    assert c.ask(METER_UNIT, read_holding(0, 1)) == hr_reply(0, 1)   # the connection goes on
    assert received(serial.record) == []
    assert received(meters.record) == [bytes((METER,)) + read_holding(0, 1)]
    assert wait_for(gw, lambda s: s["counters"]["unroutable"] == 2, "2 unroutable")


def test_a_unit_no_route_takes_is_silence_without_exception(lines, gateway, client):
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    gw = gateway(serial, meters_spec(meters))
    c = client(gw)
    c.send(bytes.fromhex("0001 0000 0006 64") + read_holding(0, 1))
    assert c.recv(NO_REPLY_S) is None
    assert c.ask(SERIAL_SLAVE, read_holding(0, 1)) == hr_reply(0, 1)   # tid 1 again: no echo
    assert received(serial.record) == [bytes((SERIAL_SLAVE,)) + read_holding(0, 1)]
    assert received(meters.record) == []


def pipelined(c: Client, unit: int, count: int, errors: list) -> None:
    """count requests in flight at once (16 at most), each reply checked: the client's tid
    and unit, the reply to its own start address."""
    try:
        frames = [struct.pack(">HHHB", tid, 0, 6, unit) + read_holding(tid % 50, 1)
                  for tid in range(1, count + 1)]
        for at in range(0, count, 8):
            c.send(*frames[at:at + 8])
            for tid in range(at + 1, min(at + 8, count) + 1):
                reply = c.recv()
                assert reply == (tid, unit, hr_reply(tid % 50, 1)), (unit, tid, reply)
    except BaseException as err:
        errors.append(err)


def test_two_clients_on_two_lines_in_parallel_get_their_own_replies(lines, gateway, client):
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    gw = gateway(serial, meters_spec(meters))
    errors: list = []
    threads = [threading.Thread(target=pipelined, args=(client(gw), unit, 40, errors))
               for unit in (SERIAL_SLAVE, METER_UNIT)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors
    assert received(serial.record) == [bytes((SERIAL_SLAVE,)) + read_holding(t % 50, 1)
                                       for t in range(1, 41)]
    assert received(meters.record) == [bytes((METER,)) + read_holding(t % 50, 1)
                                       for t in range(1, 41)]


def test_another_lines_request_does_not_wait_for_line_serials_transaction(
        lines, gateway, client):
    """While line serial waits for a silent unit, a request for meters is handed over at once
    (the reader thread) and answered before that transaction ends."""
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    gw = gateway(serial, meters_spec(meters), "--exception", "--stout", "2000")
    waiting, other = client(gw), client(gw)
    silent = SERIAL_SLAVE + 1
    waiting.send(bytes.fromhex("0007 0000 0006") + bytes((silent,)) + read_holding(0, 1))
    on_line = bytes((silent,)) + read_holding(0, 1)
    until(lambda: on_line in received(serial.record), "the request on line serial", 5)
    assert other.ask(METER_UNIT, read_holding(0, 1)) == hr_reply(0, 1)
    assert select.select([waiting.sock], [], [], 0)[0] == []   # serial is still waiting
    assert waiting.recv(5) == (7, silent, b"\x83\x0b")


def test_a_gone_clients_requests_for_another_line_never_reach_it(lines, gateway, client):
    """As a closed client's queue on line serial is discarded, its requests waiting for
    meters are dropped there before their turn."""
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    spec = meters_spec(meters)
    spec["lines"][0]["stout"] = 1000
    gw = gateway(serial, spec, "--late-window", "0")    # no wait for a late reply from 5
    silent_unit = METER_UNIT + 4                   # address 5 on meters: nobody answers
    leaving = client(gw)
    leaving.send(*(struct.pack(">HHHB", tid, 0, 6, silent_unit) + read_holding(tid, 1)
                   for tid in range(1, 7)))
    first = bytes((5,)) + read_holding(1, 1)
    until(lambda: first in received(meters.record), "the first request on meters", 5)
    leaving.close()
    staying = client(gw)
    # The first comes before the gone client's next turn (it began when that turn ended);
    # the second would come after it.
    assert staying.ask(METER_UNIT, read_holding(8, 1)) == hr_reply(8, 1)
    assert staying.ask(METER_UNIT, read_holding(9, 1)) == hr_reply(9, 1)
    assert received(meters.record) == [first, bytes((METER,)) + read_holding(8, 1),
                                       bytes((METER,)) + read_holding(9, 1)]


def test_a_lost_line_is_refused_at_once_while_the_other_answers(lines, gateway, client):
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    gw = gateway(serial, meters_spec(meters), "--exception")
    c = client(gw)
    assert c.ask(METER_UNIT, read_holding(0, 1)) == hr_reply(0, 1)
    meters.lose()
    wait_for_log(gw, f"serial device {meters.pair.gateway} lost")
    assert c.ask(METER_UNIT, read_holding(0, 1)) == b"\x83\x0a"
    assert c.ask(SERIAL_SLAVE, read_holding(1, 1)) == hr_reply(1, 1)
    assert wait_for(gw, lambda s: s["lines"][1]["state"] != "up", "meters down")["lines"][0][
        "state"] == "up"
    meters.restore()
    wait_for_log(gw, f"serial device {meters.pair.gateway} is back")
    assert c.ask(METER_UNIT, read_holding(2, 1)) == hr_reply(2, 1)
    assert c.ask(SERIAL_SLAVE, read_holding(3, 1)) == hr_reply(3, 1)
    assert received(meters.record)[-1] == bytes((METER,)) + read_holding(2, 1)


def test_line_serial_lost_leaves_the_other_lines_answering(lines, gateway, client):
    """Line serial's thread is the TCP face's home: while its device is lost it still reads
    the clients and hands the other lines' requests over."""
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    gw = gateway(serial, meters_spec(meters), "--exception")
    c = client(gw)
    serial.lose()
    wait_for_log(gw, f"serial device {serial.pair.gateway} lost")
    assert c.ask(SERIAL_SLAVE, read_holding(0, 1)) == b"\x83\x0a"
    assert c.ask(METER_UNIT, read_holding(4, 2)) == hr_reply(4, 2)
    serial.restore()
    wait_for_log(gw, f"serial device {serial.pair.gateway} is back")
    assert c.ask(SERIAL_SLAVE, read_holding(0, 1)) == hr_reply(0, 1)
    assert c.ask(METER_UNIT, read_holding(5, 1)) == hr_reply(5, 1)


def test_a_reload_adds_and_removes_a_line(tmp_path, lines, gateway, client):
    serial, meters = lines("serial", SERIAL_SLAVE), lines("meters", METER)
    config = tmp_path / "mbgw.toml"
    config_set(config, "net", "exception", "on")
    gw = gateway(serial, {"routes": [{"units": "1-31", "line": "serial"}]},
                 "--config", str(config))
    c = client(gw)
    assert c.ask(METER_UNIT, read_holding(0, 1)) == b"\x83\x0a"      # no route yet
    write_lines(tmp_path, meters_spec(meters))
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: lines, routes changed")
    assert c.ask(METER_UNIT, read_holding(0, 1)) == hr_reply(0, 1)   # same connection
    changed = meters_spec(meters)
    changed["lines"][0]["baudrate"] = 9600
    write_lines(tmp_path, changed)
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: lines changed")
    wait_for_log(gw, f"serial line settings changed: reopening {meters.pair.gateway}")
    assert c.ask(METER_UNIT, read_holding(1, 1)) == hr_reply(1, 1)
    write_lines(tmp_path, {"routes": [{"units": "1-31", "line": "serial"}]})
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: lines, routes changed", 2)
    assert c.ask(METER_UNIT, read_holding(0, 1)) == b"\x83\x0a"
    assert c.ask(SERIAL_SLAVE, read_holding(0, 1)) == hr_reply(0, 1)
    # the device is released: another program may open it now
    fd = os.open(meters.pair.gateway, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    os.close(fd)
    assert [row["name"] for row in status(gw)["lines"]] == ["serial"]
    assert received(meters.record) == [bytes((METER,)) + read_holding(0, 1),
                                       bytes((METER,)) + read_holding(1, 1)]


def test_remote_servers_answer_their_units(lines, gateway, client, servers_at):
    serial = lines("serial", SERIAL_SLAVE)
    port, _ = servers_at("127.0.0.1", silent=("127.0.0.2",))
    gw = gateway(serial, {"routes": [
        {"units": "1-31", "line": "serial"},
        {"units": "100-109", "server": ["127.0.0.1", port], "offset": -99},
        {"units": "110", "server": ["127.0.0.2", port], "address": 1},
        {"units": "111", "server": ["127.0.0.1", free_port()], "address": 1}]},
        "--exception", "--tcpto", "300")
    c = client(gw)
    # unit 101 is unit 2 on 127.0.0.1: registers 0..2 hold 0, 1 (the address) and the unit
    assert c.ask(101, read_holding(0, 3)) == bytes.fromhex("03 06 0000 0001 0002")
    assert c.ask(101, read_holding(10, 1)) == b"\x83\x02"         # the server's exception
    assert c.ask(110, read_holding(0, 1)) == b"\x83\x0b"          # silent: no reply in time
    assert c.ask(111, read_holding(0, 1)) == b"\x83\x0a"          # nobody listens there
    assert c.ask(SERIAL_SLAVE, read_holding(0, 1)) == hr_reply(0, 1)
    assert received(serial.record) == [bytes((SERIAL_SLAVE,)) + read_holding(0, 1)]


def test_a_silent_server_holds_up_its_own_requests_only(lines, gateway, client, servers_at):
    serial = lines("serial", SERIAL_SLAVE)
    port, _ = servers_at("127.0.0.1", silent=("127.0.0.2",))
    gw = gateway(serial, {"routes": [
        {"units": "1-31", "line": "serial"},
        {"units": "100", "server": ["127.0.0.2", port], "address": 1},     # silent
        {"units": "101", "server": ["127.0.0.1", port], "address": 2}]},
        "--exception", "--tcpto", "5000")
    waiting, other = client(gw), client(gw)
    waiting.send(mbap(1, 100, read_holding(0, 1)))
    # the silent server's request is on its connection (the servers' peer saw it connect)
    # while another server answers at once: its reply comes before the silent one's 0x0B
    assert other.ask(101, read_holding(0, 3)) == bytes.fromhex("03 06 0000 0001 0002")
    assert other.ask(SERIAL_SLAVE, read_holding(0, 1)) == hr_reply(0, 1)
    assert waiting.recv(timeout=0.01) is None        # still waiting for its server
    assert waiting.recv(timeout=10) == (1, 100, b"\x83\x0b")


def test_each_servers_figures_in_status_and_metrics(lines, gateway, client, servers_at):
    serial = lines("serial", SERIAL_SLAVE)
    port, _ = servers_at("127.0.0.1", silent=("127.0.0.2",))
    closed = free_port()
    metrics_port = free_port()
    gw = gateway(serial, {"routes": [
        {"units": "1-31", "line": "serial"},
        {"units": "100-109", "server": ["127.0.0.1", port], "offset": -99},
        {"units": "110", "server": ["127.0.0.2", port], "address": 1},
        {"units": "111", "server": ["127.0.0.1", closed], "address": 1}]},
        "--exception", "--tcpto", "300", "--metrics", f"127.0.0.1:{metrics_port}")
    c = client(gw)
    for start in range(3):
        assert c.ask(101, read_holding(start, 1)) == bytes((3, 2, 0, start))
    assert c.ask(101, read_holding(10, 1)) == b"\x83\x02"         # the server's exception
    assert c.ask(110, read_holding(0, 1)) == b"\x83\x0b"          # silent: no reply in time
    assert c.ask(111, read_holding(0, 1)) == b"\x83\x0a"          # nobody listens there
    answering, silent, absent = (f"127.0.0.1:{port}", f"127.0.0.2:{port}",
                                 f"127.0.0.1:{closed}")
    rows = {row["server"]: row for row in status(gw)["servers"]}
    assert set(rows) == {answering, silent, absent}
    figures = ("requests", "replies", "device_exceptions", "gateway_exceptions", "timeouts",
               "unreachable", "connections_opened")
    expected = {answering: (4, 4, 1, 0, 0, 0, 1), silent: (1, 0, 0, 1, 1, 0, 1),
                absent: (1, 0, 0, 1, 0, 1, 0)}
    for server, values in expected.items():
        assert tuple(rows[server]["counters"][n] for n in figures) == values, server
    assert [conn["server"] for conn in rows[answering]["connections"]] == [answering]
    assert rows[absent]["connections"] == []

    text = mbgw("status", "--control", gw.control)
    assert text.returncode == 0, text.stderr
    shown = {row.split()[0]: row.split()[1:] for row in text.stdout.splitlines()
             if row.startswith("  127.0.0.")}
    # SERVER REQUESTS REPLIES EXCEPT TIMEOUTS UNREACH OPEN OPENED LOST
    assert shown[answering] == ["4", "4", "1", "0", "0", "1", "1", "0"]
    assert shown[absent] == ["1", "0", "0", "0", "1", "0", "0", "0"]

    families = scraped(metrics_port)
    for server, values in expected.items():
        for name, value in zip(figures, values, strict=True):
            assert metric_value(families, f"mbgw_server_{name}", f"mbgw_server_{name}_total",
                                server=server) == value, (server, name)
    assert metric_value(families, "mbgw_server_connections", server=answering) == 1
    assert metric_value(families, "mbgw_server_connections", server=absent) == 0
