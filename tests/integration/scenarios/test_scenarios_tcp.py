"""TCP scenarios (issue 15): the runner (mbgw.scenarios.tcp_runner) against pymodbus's TCP
server and a scripted misbehaving one (tests/peers/scripted_tcp_server.py).

The runner's contract with the engine is checked here with a stand-in engine that hands out
the runs the test queues and records what the runner reports for each (reply, error kind,
retries); the requests are checked on the wire, as the server saw them."""
import json
import os
import queue
import signal
import struct
import threading
from dataclasses import dataclass

import pytest

from mbgw.ops.eventfd import drain
from mbgw.scenarios.tcp_runner import (
    CONNECTION_LOST,
    CONNECTION_REFUSED,
    TIMEOUT,
    TcpRunner,
)
from tests.harness import Peer, free_port
from tests.integration.ops.test_trace_raw import Trace
from tests.modbus import Client
from tests.ops import mbgw, metric_value, scraped, status, wait_for_log
from tests.peers.scripted_tcp_server import ScriptedServer
from tests.wait import until

pytestmark = pytest.mark.integration

TCPTO_MS = 300
READ_3 = bytes([3, 0, 0, 0, 3])             # FC 3, 3 registers from 0


@dataclass(frozen=True)
class Scenario:
    server: str
    unit: int = 1
    retries: int = 0
    tls: bool = False
    name: str = "stand-in"


@dataclass
class Run:
    scenario: Scenario
    pdu: bytes
    probe: bool = False


class StandInEngine:
    """The engine's side of the runner: next() hands out the runs queued, done() records."""

    def __init__(self) -> None:
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._runs: list[Run] = []
        self._lock = threading.Lock()
        self.results: queue.Queue = queue.Queue()
        self.retried: list = []         # the scenarios told "retrying", in order

    def queue(self, scenario: Scenario, pdu: bytes = READ_3) -> None:
        with self._lock:
            self._runs.append(Run(scenario, pdu))
        os.eventfd_write(self.wake_fd, 1)

    def tick(self, now) -> None:
        pass

    def take_test(self, now):
        return None

    def due_in(self, now):
        return 0 if self._runs else None

    def next(self, now):
        drain(self.wake_fd)
        with self._lock:
            return self._runs.pop(0) if self._runs else None

    def reconfigure(self, configs) -> None:
        pass

    def done(self, run, reply, kind, retries) -> None:
        self.results.put((reply, kind, retries))

    def retrying(self, scenario) -> None:
        self.retried.append(scenario)

    def result(self):
        return self.results.get(timeout=10)


@pytest.fixture
def runner():
    engine = StandInEngine()
    run = TcpRunner(engine, TCPTO_MS)
    run.start()
    yield run
    run.stop()
    run.join()
    os.close(engine.wake_fd)


@pytest.fixture
def scripted():
    servers = []

    def start(*script, values=(0x1234,), port=0, host="127.0.0.1") -> ScriptedServer:
        server = ScriptedServer(values, script, port, host)
        servers.append(server)
        return server
    yield start
    for server in servers:
        server.stop()


def registers(*values: int) -> bytes:
    return bytes([3, 2 * len(values)]) + struct.pack(f">{len(values)}H", *values)


def test_a_read_from_pymodbus_server_comes_back_to_the_engine(runner):
    port = free_port()
    peer = Peer("pymodbus_tcp_servers.py", str(port), "127.0.5.1")
    try:
        runner.engine.queue(Scenario(f"127.0.5.1:{port}", unit=7))
        # holding registers of unit u on a.b.c.d: c, d, u
        assert runner.engine.result() == (registers(5, 1, 7), None, 0)
    finally:
        peer.stop()


def test_each_failure_has_its_kind_and_the_wire_saw_each_request(runner, scripted):
    server = scripted("wrong-function", "wrong-quantity", ("exception", 2), ("exception", 0x0B),
                      "silent", "close", "ok", values=(9,))
    sc = Scenario(server.server, unit=3)
    for _ in range(7):
        runner.engine.queue(sc)
    results = [runner.engine.result() for _ in range(7)]
    # a reply that does not answer goes to the engine, which tells what is wrong with it
    assert results[0] == (bytes([4, 6]) + struct.pack(">3H", 9, 9, 9), None, 0)
    assert results[1] == (registers(9, 9), None, 0)
    assert results[2] == (bytes([0x83, 2]), None, 0)
    assert results[3] == (bytes([0x83, 0x0B]), None, 0)
    assert results[4] == (None, TIMEOUT, 0)
    assert results[5] == (None, CONNECTION_LOST, 0)
    assert results[6] == (registers(9, 9, 9), None, 0)
    assert server.wait_requests(7) == [(3, READ_3)] * 7


def test_an_ipv6_server(runner, scripted):
    server = scripted(values=(6,), host="::1")
    runner.engine.queue(Scenario(f"[::1]:{server.port}"))
    assert runner.engine.result() == (registers(6, 6, 6), None, 0)


def test_retries_after_a_timeout_and_a_lost_connection(runner, scripted):
    server = scripted("silent", "close", "ok", values=(1, 2, 3))
    scenario = Scenario(server.server, retries=2)
    runner.engine.queue(scenario)
    assert runner.engine.result() == (registers(1, 2, 3), None, 2)
    assert server.wait_requests(3) == [(1, READ_3)] * 3
    assert runner.engine.retried == [scenario, scenario]     # "server not responding, ..."
    runner.engine.queue(Scenario(server.server, retries=1), bytes([6, 0, 4, 0, 7]))
    assert runner.engine.result() == (bytes([6, 0, 4, 0, 7]), None, 0)
    server.script.extend(["silent", "silent"])
    runner.engine.queue(Scenario(server.server, retries=1))
    assert runner.engine.result() == (None, TIMEOUT, 1)


def test_a_refused_server_backs_off_then_recovers(runner, scripted):
    port = free_port()
    sc = Scenario(f"127.0.0.1:{port}", retries=2)
    runner.engine.queue(sc)
    assert runner.engine.result() == (None, CONNECTION_REFUSED, 0)
    runner.engine.queue(sc)         # within the backoff: not tried, the same failure
    assert runner.engine.result() == (None, CONNECTION_REFUSED, 0)
    server = scripted(port=port)
    while True:                     # until its backoff has passed
        runner.engine.queue(sc)
        reply, kind, _ = runner.engine.result()
        if kind is None:
            break
        assert kind == CONNECTION_REFUSED
    assert reply == registers(0x1234, 0x1234, 0x1234)
    assert server.connections == 1


def test_a_server_that_comes_back_after_closing_is_reconnected(runner, scripted):
    server = scripted()
    sc = Scenario(server.server)
    runner.engine.queue(sc)
    assert runner.engine.result()[1] is None
    port = server.port
    server.stop()
    runner.engine.queue(sc)
    assert runner.engine.result()[1] in (CONNECTION_LOST, CONNECTION_REFUSED)
    again = scripted(port=port)
    while True:
        runner.engine.queue(sc)
        reply, kind, _ = runner.engine.result()
        if kind is None:
            break
    assert again.wait_requests(1)[-1] == (1, READ_3)


def test_stop_does_not_wait_for_tcpto(scripted):
    engine = StandInEngine()
    run = TcpRunner(engine, 60_000)
    run.start()
    server = scripted("silent")
    engine.queue(Scenario(server.server))
    server.wait_requests(1)
    run.stop()
    run.join()            # the test's own timeout would catch a wait of tcpto
    assert engine.results.empty()
    os.close(engine.wake_fd)


def test_work_handed_over_runs_on_the_runner_thread(runner):
    names = runner.call(lambda: threading.current_thread().name).result(timeout=5)
    assert names == "mbgw-scenarios-tcp"


# --- in the daemons: the data lands in the table, read back over the table's TCP side -------

SERVER = "127.0.8.1"            # pymodbus: holding registers of unit u: 8, 1, u, 103..
FREE = 0x1000                   # the table's free zone
TABLE_UNIT = 247                # slave mode: a unit of the table (direct messaging)
FAST_TCPTO_MS = 300
CONDITION_S = 15.0


def scenario_toml(name: str, server: str, **keys) -> str:
    lines = [f'[[scenario]]\nname = "{name}"\nserver = "{server}"']
    for key, value in keys.items():
        text = f'"{value}"' if isinstance(value, str) else str(value).lower() \
            if isinstance(value, bool) else str(value)
        lines.append(f"{key.replace('_', '-')} = {text}")
    return "\n".join(lines) + "\n"


def read_table(port: int, unit: int, address: int, count: int) -> list[int] | bytes:
    """FC 3 over the table's TCP side: the registers, or the exception PDU."""
    client = Client(port)
    try:
        reply = client.ask(unit, struct.pack(">BHH", 3, address, count))
    finally:
        client.close()
    if reply[0] & 0x80:
        return reply
    return list(struct.unpack(f">{count}H", reply[2:]))


def write_table(port: int, unit: int, address: int, *values: int) -> None:
    client = Client(port)
    try:
        pdu = struct.pack(f">BHHB{len(values)}H", 16, address, len(values), 2 * len(values),
                          *values)
        assert client.ask(unit, pdu) == pdu[:5]
    finally:
        client.close()


def scenario_status(gw, name: str) -> dict:
    return next(s for s in status(gw)["scenarios"] if s["name"] == name)


@pytest.fixture
def master_with(tmp_path, start_master):
    """master_with(scenarios_toml, tcpto) -> (gateway, table port): `mbgw master` with an
    empty slaveid table and the table served on a free port, from a file."""
    def start(scenarios: str, *options: str, tcpto: int = FAST_TCPTO_MS):
        table_port = free_port()
        path = tmp_path / "mbgw.toml"
        path.write_text(f'[serial]\nmode = "master"\nbaudrate = 19200\n\n[net]\n'
                        f'tcpto = {tcpto}\n\n[table]\nenabled = true\nport = {table_port}\n\n'
                        + scenarios)
        return start_master("--config", str(path), *options), table_port, path
    return start


@pytest.fixture
def slave_with(tmp_path, pty_pair, start_gateway):
    """slave_with(scenarios_toml, serial=more [serial] lines) -> gateway: `mbgw slave` with
    the table (units 247-254) and these scenarios, from a file; nothing on its serial
    line."""
    def start(scenarios: str, tcpto: int = FAST_TCPTO_MS, serial: str = ""):
        path = tmp_path / "mbgw.toml"
        path.write_text(f'[serial]\nbaudrate = 19200\n{serial}\n[net]\ntcpto = {tcpto}\n\n'
                        f'[table]\nenabled = true\n\n' + scenarios)
        return start_gateway(pty_pair.gateway, "--config", str(path)), path
    return start


def test_master_mode_polls_pymodbus_into_the_table(servers_at, master_with):
    port, _ = servers_at(SERVER)
    metrics_port = free_port()
    gw, table_port, _ = master_with(scenario_toml(
        "boiler", f"{SERVER}:{port}", unit=5, function=3, address=0, quantity=3, table=FREE,
        cycle=100), "--metrics", f"127.0.0.1:{metrics_port}")
    until(lambda: read_table(table_port, 1, FREE, 3) == [8, 1, 5],
          "the data in the table", CONDITION_S)
    s = until(lambda: (s := scenario_status(gw, "boiler"))["successes"] and s,
              "a success", CONDITION_S)
    assert s["state"] == "running" and s["kind"] == "tcp"
    families = scraped(metrics_port)
    assert metric_value(families, "mbgw_scenario_runs", "mbgw_scenario_runs_total",
                        scenario="boiler") >= 1
    assert metric_value(families, "mbgw_scenario_state", state="running",
                        scenario="boiler") == 1


def test_slave_mode_polls_and_writes_on_change(slave_with, scripted):
    server = scripted(values=(0x0102,))
    gw, _ = slave_with(
        scenario_toml("poll", server.server, unit=9, function=3, address=4, quantity=2,
                      table=FREE, cycle=100)
        + scenario_toml("push", server.server, unit=9, function=16, address=20, quantity=2,
                        table=FREE + 0x10, trigger="change"))
    until(lambda: read_table(gw.port, TABLE_UNIT, FREE, 2) == [0x0102, 0x0102],
          "read data", CONDITION_S)
    assert (9, bytes([3, 0, 4, 0, 2])) in server.wait_requests(1)

    def writes():
        return [pdu for _, pdu in server.requests if pdu[0] == 16]

    write_table(gw.port, TABLE_UNIT, FREE + 0x10, 7, 8)
    until(lambda: writes(), "a write on change", CONDITION_S)
    write_table(gw.port, TABLE_UNIT, FREE + 0x10, 7, 8)          # the same values: no write
    write_table(gw.port, TABLE_UNIT, FREE + 0x10, 7, 9)          # a new value: one write
    until(lambda: len(writes()) >= 2, "the second write", CONDITION_S)
    assert writes() == [bytes([16, 0, 20, 0, 2, 4, 0, 7, 0, 8]),
                        bytes([16, 0, 20, 0, 2, 4, 0, 7, 0, 9])]


def test_a_tcp_scenarios_runs_are_in_the_trace_with_its_name(slave_with, scripted):
    """`mbgw trace --scenario poll`: the request the scripted server received and the reply
    it sent, marked with the scenario's name; not on the serial line (--line serial)."""
    server = scripted(values=(0x0102,))
    gw, _ = slave_with(scenario_toml("poll", server.server, unit=9, function=3, address=4,
                                     quantity=2, table=FREE, cycle=100))
    trace = Trace(gw, "--scenario", "poll")
    on_serial = Trace(gw, "--line", "serial", "--count", "1")
    try:
        lines = [line.replace("scenario poll", "scenario:poll").split()
                 for line in trace.lines(5)[1:]]
        first = next(i for i, line in enumerate(lines) if line[1] == "request")
        request, reply = lines[first], lines[first + 1]
        assert request[1:6] == ["request", "scenario:poll", "-", "9", "0x03"], lines
        assert reply[1:6] + reply[7:8] == ["reply", "scenario:poll", "-", "9", "0x03", "ok"]
        assert (9, bytes([3, 0, 4, 0, 2])) in server.requests
        assert on_serial.proc.poll() is None       # nothing on the serial line to show
    finally:
        trace.stop()
        on_serial.stop()


# VPGate's messages (§8.2), a TCP scenario's peer called a server
@pytest.mark.parametrize("action, message", [
    ("wrong-function", "received unexpected function in answer"),
    ("wrong-quantity", "received unexpected data/quantity in answer"),
    (("exception", 2), "received illegal data address from server (0x02)"),
    (("exception", 0x0B), "gateway target failed to respond (0x0B)"),
    ("silent", "timeout, no answer from server after retrying"),
    ("close", "TCP connection lost"),
])
def test_a_failing_server_puts_the_scenario_in_error_then_it_recovers(
        slave_with, scripted, action, message):
    server = scripted()
    server.default = action
    gw, _ = slave_with(scenario_toml("flaky", server.server, function=3, address=0,
                                     quantity=2, table=FREE, cycle=100),
                       serial="down-after = 0\n")     # every run dials: its own message
    until(lambda: scenario_status(gw, "flaky")["message"] == message, message, CONDITION_S)
    server.default = "ok"
    s = until(lambda: (s := scenario_status(gw, "flaky"))["state"] == "running" and s,
              "recovery", CONDITION_S)
    assert s["successes"] >= 1
    assert read_table(gw.port, TABLE_UNIT, FREE, 2) == [0x1234, 0x1234]


def test_a_refused_server_then_its_return(slave_with, scripted):
    port = free_port()
    gw, _ = slave_with(scenario_toml("later", f"127.0.0.1:{port}", function=3, address=0,
                                     quantity=1, table=FREE, cycle=100))
    until(lambda: scenario_status(gw, "later")["message"] == "connection refused",
          "refused", CONDITION_S)
    server = scripted(values=(42,), port=port)
    until(lambda: read_table(gw.port, TABLE_UNIT, FREE, 1) == [42],
          "the data after recovery", CONDITION_S)
    assert scenario_status(gw, "later")["state"] == "running"
    assert server.connections == 1


def test_reload_starts_and_stops_the_tcp_scenarios(slave_with, scripted):
    server = scripted(values=(5,))
    gw, path = slave_with("")
    text = path.read_text()
    path.write_text(text + scenario_toml("added", server.server, function=3, address=0,
                                         quantity=1, table=FREE, cycle=100))
    os.kill(gw.proc.pid, signal.SIGHUP)
    until(lambda: read_table(gw.port, TABLE_UNIT, FREE, 1) == [5],
          "the added scenario's data", CONDITION_S)
    path.write_text(text)
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "no TCP scenarios any more")        # the runner has ended
    until(lambda: server.disconnections, "the connection closed", CONDITION_S)
    write_table(gw.port, TABLE_UNIT, FREE, 0)             # a round trip through the gateway
    assert server.connections == 1


def test_scenario_test_and_disable_in_master_mode(servers_at, master_with, scripted):
    """`mbgw scenario test` runs once on the TCP runner (its data printed, not stored);
    `mbgw scenario disable` stops a scenario's runs until enabled again."""
    port, _ = servers_at(SERVER)
    server = scripted(values=(3,))
    gw, table_port, _ = master_with(scenario_toml(
        "ticker", server.server, function=3, address=0, quantity=1, table=FREE, cycle=100))
    result = mbgw("scenario", "test", f"server={SERVER}:{port}", "unit=6", "function=3",
                  "address=0", "quantity=3", f"table={FREE + 0x20}", "cycle=1000", "--json",
                  "--control", gw.control)
    assert result.returncode == 0, result.stderr
    reply = json.loads(result.stdout)
    assert reply["ok"] and reply["data"] == [8, 1, 6], reply
    assert read_table(table_port, 1, FREE + 0x20, 3) == [0, 0, 0]     # not stored

    until(lambda: read_table(table_port, 1, FREE, 1) == [3], "the cyclic data", CONDITION_S)
    result = mbgw("scenario", "disable", "ticker", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    assert scenario_status(gw, "ticker")["state"] == "disabled"
    seen = len(server.requests)
    server.values = [4]
    result = mbgw("scenario", "test", f"server={server.server}", "function=3", "address=0",
                  "quantity=1", f"table={FREE}", "cycle=1000", "--json", "--control", gw.control)
    assert json.loads(result.stdout)["data"] == [4]
    assert len(server.requests) == seen + 1            # the test's, no run of ticker's
    assert read_table(table_port, 1, FREE, 1) == [3]
    result = mbgw("scenario", "enable", "ticker", "--control", gw.control)
    assert result.returncode == 0, result.stderr
    until(lambda: read_table(table_port, 1, FREE, 1) == [4], "the runs again", CONDITION_S)


def test_stale_data_is_refused_over_tcp_until_the_server_answers_again(slave_with, scripted):
    server = scripted(values=(11,))
    gw, _ = slave_with(scenario_toml("fresh", server.server, function=3, address=0,
                                     quantity=2, table=FREE, cycle=100, stale_after=500,
                                     retries=0))
    until(lambda: read_table(gw.port, TABLE_UNIT, FREE, 2) == [11, 11], "the data", CONDITION_S)
    server.default = "silent"
    until(lambda: read_table(gw.port, TABLE_UNIT, FREE, 2) == bytes([0x83, 0x0B]),
          "0x0B for stale data", CONDITION_S)
    assert read_table(gw.port, TABLE_UNIT, FREE + 2, 1) == [0]     # the register after: served
    server.default = "ok"
    until(lambda: read_table(gw.port, TABLE_UNIT, FREE, 2) == [11, 11],
          "fresh data again", CONDITION_S)


def test_transparent_mode_runs_tcp_scenarios_beside_its_frames(tmp_path, pty_pair,
                                                               start_gateway, servers_at):
    """Issue 16: TCP scenarios run in transparent mode too, into the table its clients read;
    a serial scenario there is refused, naming it."""
    port, _ = servers_at(SERVER)
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\nmode = "transparent"\nbaudrate = 19200\n\n[net]\ntcpto = '
                    f'{FAST_TCPTO_MS}\n\n' + scenario_toml(
                        "meter", f"{SERVER}:{port}", unit=6, function=3, address=0,
                        quantity=3, table=FREE, cycle=100))
    gw = start_gateway(pty_pair.gateway, "--config", str(path), mode="transparent")
    until(lambda: read_table(gw.port, 1, FREE, 3) == [8, 1, 6],
          "the data in the table", CONDITION_S)
    assert until(lambda: scenario_status(gw, "meter")["successes"], "a success", CONDITION_S)
    shown = mbgw("scenarios", "--control", gw.control)
    assert shown.returncode == 0 and "meter" in shown.stdout

    bad = tmp_path / "bad.toml"
    bad.write_text('[serial]\nmode = "transparent"\n\n[[scenario]]\nname = "local"\nslave = 3\n'
                   'function = 3\naddress = 0\nquantity = 1\ntable = 0\ncycle = 1000\n')
    checked = mbgw("check-config", str(bad))
    assert checked.returncode != 0
    assert "scenario local: slave: transparent mode's line carries raw frames" in \
        checked.stdout + checked.stderr
