"""TCP scenarios (issue 15): the runner (mbgw.scenarios.tcp_runner) against pymodbus's TCP
server and a scripted misbehaving one (tests/peers/scripted_tcp_server.py).

The runner's contract with the engine is checked here with a stand-in engine that hands out
the runs the test queues and records what the runner reports for each (reply, error kind,
retries); the requests are checked on the wire, as the server saw them."""
import os
import queue
import struct
import threading
from dataclasses import dataclass

import pytest

from mbgw.scenarios.tcp_runner import (
    CONNECTION_LOST,
    CONNECTION_REFUSED,
    TIMEOUT,
    TcpRunner,
    split_server,
)
from tests.harness import Peer, free_port
from tests.peers.scripted_tcp_server import ScriptedServer

pytestmark = pytest.mark.integration

TCPTO_MS = 300
READ_3 = bytes([3, 0, 0, 0, 3])             # FC 3, 3 registers from 0


@dataclass(frozen=True)
class Scenario:
    server: str
    unit: int = 1
    retries: int = 0


@dataclass
class Run:
    scenario: Scenario
    pdu: bytes


class StandInEngine:
    """The engine's side of the runner: next() hands out the runs queued, done() records."""

    def __init__(self) -> None:
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._runs: list[Run] = []
        self._lock = threading.Lock()
        self.results: queue.Queue = queue.Queue()

    def queue(self, scenario: Scenario, pdu: bytes = READ_3) -> None:
        with self._lock:
            self._runs.append(Run(scenario, pdu))
        os.eventfd_write(self.wake_fd, 1)

    def due_in(self, now):
        return 0 if self._runs else None

    def next(self, now):
        with self._lock:
            return self._runs.pop(0) if self._runs else None

    def reconfigure(self, configs) -> None:
        pass

    def done(self, run, reply, kind, retries) -> None:
        self.results.put((reply, kind, retries))

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

    def start(*script, values=(0x1234,), port=0) -> ScriptedServer:
        server = ScriptedServer(values, script, port)
        servers.append(server)
        return server
    yield start
    for server in servers:
        server.stop()


def registers(*values: int) -> bytes:
    return bytes([3, 2 * len(values)]) + struct.pack(f">{len(values)}H", *values)


def test_server_addresses_split_into_host_and_port():
    assert split_server("10.0.0.1:1502") == ("10.0.0.1", 1502)
    assert split_server("10.0.0.1") == ("10.0.0.1", 502)
    assert split_server("[::1]:1502") == ("::1", 1502)
    assert split_server("[::1]") == ("::1", 502)
    assert split_server("plc.example:503") == ("plc.example", 503)


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


def test_retries_after_a_timeout_and_a_lost_connection(runner, scripted):
    server = scripted("silent", "close", "ok", values=(1, 2, 3))
    runner.engine.queue(Scenario(server.server, retries=2))
    assert runner.engine.result() == (registers(1, 2, 3), None, 2)
    assert server.wait_requests(3) == [(1, READ_3)] * 3
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


