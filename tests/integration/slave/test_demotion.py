"""Demotion: a serial address whose requests fail --down-after times in a row is down.  While
it is down its requests are refused at once and never go on the line (in master mode, never
to its server), 0x0B with --exception and nothing without, counted as demoted_rejects; one
request per --probe-interval goes all the same, as a probe, the interval doubling while the
probes fail; the first answer (an exception reply is one) makes the address up again.

Slave mode: the scripted slave of tests/peers/fault_slave.py records each frame it receives
with its arrival time (time.monotonic(), which is the test's clock too); its address 14 is
silent to its first --mute-first requests, then answers.  What went on the line is read from
that record, never from mbgw's counters.  A request for address 1 (always answered) sent
behind the ones under test is the event that says the line has carried everything before
it.  Every slave-mode test runs with the idle line's shortcut (C puts a request that finds
the line idle on it) and without.  Master mode: a scripted Modbus TCP server
(test_master_replies.ScriptedServer) that stays silent for a number of requests, and the
serial master is the test on the pty.

Probes are checked against the windows they must respect: each one at least the interval
(doubled after each failed probe) after the failure before it, timed by the peer's clock; no
test waits for a duration or asserts that something happened within one.
"""
import os
import signal
import time

import pytest

from tests.harness import free_port, stop_counters
from tests.integration.master.rig import ask, unanswered
from tests.integration.master.rig import probed as probed_on_line
from tests.integration.master.rig import read_holding as serial_read
from tests.integration.master.test_master_replies import ScriptedServer, read_reply
from tests.integration.master.test_master_replies import mbap as server_mbap
from tests.integration.slave.test_faults import received
from tests.modbus import Client, holding_reply, mbap, read_holding
from tests.ops import devices, health_log, mbgw, status, wait_for, wait_for_log

pytestmark = pytest.mark.integration

STOUT_MS = 200
INTERVAL_MS = 250             # above stout: a request that is not refused would come sooner
INTERVAL_S = INTERVAL_MS / 1000
DOWN_AFTER = 2
MUTED = 14                    # fault_slave: silent to its first --mute-first requests
SILENT = 2                    # fault_slave: never answers
EXCEPTION = 11                # fault_slave: always exception 02
READ = read_holding(0, 1)
REPLY = holding_reply(0, 1)
NO_ANSWER = b"\x83\x0b"
GIVE_UP_S = 30.0              # a probe that never comes fails the test after this


# --- slave mode -----------------------------------------------------------------------------

@pytest.fixture
def gateway(pty_pair, recording_peer, start_gateway, shortcut_both_ways):
    """gateway(*options, mute_first=3) -> (a ready gateway, stout STOUT_MS, demoted after
    DOWN_AFTER failures and probed every INTERVAL_MS unless told; the record of the fault
    slave on its line)."""
    def start(*options: str, mute_first: int = 3):
        record = recording_peer("fault_slave.py", "--mute-first", str(mute_first))
        gw = start_gateway(pty_pair.gateway, "--baudrate", "38400", "--stout", str(STOUT_MS),
                           "--down-after", str(DOWN_AFTER), "--probe-interval",
                           str(INTERVAL_MS), *shortcut_both_ways, *options)
        return gw, record
    return start


def on_line(record, address: int) -> list[float]:
    """When each frame for address reached the slave."""
    return [when for when, frame in received(record) if frame[0] == address]


class Asker:
    """One client's requests, each on its own (so that a request finding the line idle may
    take the shortcut), then one for address 1 behind it: its reply says the line carried
    whatever was before it.  exception: the gateway answers 0x0B for a request that gets no
    reply."""

    def __init__(self, c: Client, exception: bool) -> None:
        self.c = c
        self.exception = exception
        self.tid = 0
        self.sent = 0

    def ask(self, unit: int) -> bytes | None:
        """unit's answer (its PDU), or None when it got none."""
        self.tid += 1
        tid = self.tid
        self.c.send(mbap(tid, unit, READ))
        self.sent += 1
        answer = self.c.recv() if self.exception else None
        if answer is not None:
            assert answer[:2] == (tid, unit), answer
        self.tid += 1
        self.c.send(mbap(self.tid, 1, READ))
        got = self.c.recv()
        if got is not None and got[0] == tid:          # no --exception: its reply came first
            answer, got = got, self.c.recv()
        assert got == (self.tid, 1, REPLY), got
        return None if answer is None else answer[2]


def probed(c: Client, unit: int, request: bytes, reply: bytes) -> int:
    """Send the request until it is answered `reply`: the probe of an address that is down
    (--exception on).  Every answer before it must be 0x0B, the gateway's.  Returns how many
    there were."""
    deadline = time.monotonic() + GIVE_UP_S
    tid, refused = 1000, 0
    while True:
        tid += 1
        c.send(mbap(tid, unit, request))
        got = c.recv()
        if got != (tid, unit, bytes((request[0] | 0x80, 0x0B))):
            assert got == (tid, unit, reply), got
            return refused
        refused += 1
        assert time.monotonic() < deadline, f"no probe after {refused} refusals"


@pytest.mark.serial          # the down rule counts time as well as failures
@pytest.mark.parametrize("exception", [True, False], ids=["exception", "silence"])
def test_a_silent_address_is_refused_at_once_probed_at_the_interval_and_back_on_its_answer(
        gateway, client, exception):
    """Address 14 does not answer its first 4 requests: 2 make it down; then every request is
    refused, and the line thread probes it itself with the first request that timed out, at
    INTERVAL, twice and 4 times INTERVAL after the failures before them; the third probe is
    answered, and the address serves again.  (Before issue 29 a client's request was the
    probe; it is now only when no request is kept to probe with.)  The interval is 300 ms
    here: the address stays down 2.1 s, five times what an operator's `mbgw status` takes to
    start."""
    probe_ms = 300
    probe_s = probe_ms / 1000
    gw, record = gateway(*(["--exception"] if exception else []), "--probe-interval",
                         str(probe_ms), mute_first=DOWN_AFTER + 2)
    asker = Asker(client(gw), exception)
    refusal = NO_ANSWER if exception else None
    for _ in range(DOWN_AFTER):
        assert asker.ask(MUTED) == refusal
    assert len(on_line(record, MUTED)) == DOWN_AFTER
    s = wait_for(gw, lambda s: True, "status")     # in process: no CLI to start first
    assert devices(s)[MUTED]["health"] == "down"
    # the operator sees the rule and when the next probe may go (the line thread may have
    # probed already on a loaded host: then within the doubled interval, 1.2 s at most here)
    assert s["demotion"] == {"down_after": DOWN_AFTER, "probe_interval_ms": probe_ms}
    assert 0 <= devices(s)[MUTED]["next_probe_in_s"] <= 4 * probe_s
    shown = mbgw("status", "--control", gw.control).stdout
    assert f"down after {DOWN_AFTER} failures in a row, then a probe every {probe_ms} ms" \
        in shown and "        next probe in " in shown

    # down: refused at once, and nothing goes on the line (this request finds the line idle
    # since long: with the shortcut on, C reads it, and must hand it back) -- unless the
    # machine is so loaded that it comes INTERVAL after the failure: then it is the first probe
    assert asker.ask(MUTED) == refusal
    if len(on_line(record, MUTED)) == DOWN_AFTER:
        assert status(gw)["counters"]["demoted_rejects"] == 1
    deadline = time.monotonic() + GIVE_UP_S
    while (answer := asker.ask(MUTED)) == refusal:
        assert time.monotonic() < deadline, "the address never came back"
    assert answer == REPLY
    assert asker.ask(MUTED) == REPLY                    # up again: it goes on the line

    frames = on_line(record, MUTED)
    assert len(frames) == DOWN_AFTER + 5                # 3 probes, then the 2 requests after
    assert {f[:1 + len(READ)] for _, f in received(record) if f[0] == MUTED} == \
        {bytes((MUTED,)) + READ}
    failed_at = frames[DOWN_AFTER - 1]                  # the request that made it down
    for n, probe in enumerate(frames[DOWN_AFTER:DOWN_AFTER + 3]):
        # at least the window after the failure before it (that failure came stout after
        # the frame before it: a margin for the peer's clock)
        assert probe - failed_at >= probe_s * 2 ** n, (n, frames)
        failed_at = probe
    probes = 3
    refused = asker.sent - (len(frames) - probes)
    assert refused > 0

    s = status(gw)
    d = devices(s)[MUTED]
    assert (d["health"], d["consecutive_failures"]) == ("degraded", 0)
    assert d["demoted_rejects"] == s["counters"]["demoted_rejects"] == refused
    assert (d["transactions"], d["timeouts"], d["replies"]) == (len(frames), DOWN_AFTER + 2, 3)
    # the probes had no client to answer: only the clients' requests had 0x0B
    assert d["gateway_exceptions"] == ({"0x0b": DOWN_AFTER + refused} if exception else {})
    assert health_log(gw, MUTED) == ["degraded", "down", "degraded"]
    assert f"device {MUTED} is down: {DOWN_AFTER} requests in a row without a valid reply; " \
           f"its requests are refused, but for a probe every {probe_s:g} s, backing off to 60 s" \
           in gw.log()
    assert devices(s)[1]["demoted_rejects"] == 0
    assert stop_counters(gw)["demoted_rejects"] == refused


@pytest.mark.serial          # the down rule counts time as well as failures
def test_requests_queued_before_the_address_went_down_never_reach_the_line(gateway, client):
    """4 requests pipelined at once: the first 2 fail and make the address down; the other 2,
    queued meanwhile, are refused when their turn comes instead of costing stout each."""
    gw, record = gateway("--exception", "--probe-interval", "60000")    # no probe meanwhile
    c = client(gw)
    c.send(*(mbap(tid, SILENT, READ) for tid in range(1, 5)), mbap(5, 1, READ))
    assert [c.recv() for _ in range(5)] == [
        *((tid, SILENT, NO_ANSWER) for tid in range(1, 5)), (5, 1, REPLY)]
    assert len(on_line(record, SILENT)) == DOWN_AFTER
    s = status(gw)
    assert devices(s)[SILENT]["demoted_rejects"] == s["counters"]["demoted_rejects"] == 2
    assert devices(s)[SILENT]["timeouts"] == DOWN_AFTER


def test_an_address_that_answers_with_an_exception_is_alive(gateway, client):
    gw, record = gateway("--exception")
    asker = Asker(client(gw), exception=True)
    for _ in range(3 * DOWN_AFTER):
        assert asker.ask(EXCEPTION) == b"\x83\x02"
    assert len(on_line(record, EXCEPTION)) == 3 * DOWN_AFTER
    d = devices(status(gw))[EXCEPTION]
    assert (d["health"], d["replies"], d["demoted_rejects"]) == ("up", 3 * DOWN_AFTER, 0)


def test_down_after_0_never_demotes(gateway, client):
    gw, record = gateway("--exception", "--down-after", "0")
    asker = Asker(client(gw), exception=True)
    for _ in range(DOWN_AFTER + 2):
        assert asker.ask(SILENT) == NO_ANSWER
    assert len(on_line(record, SILENT)) == DOWN_AFTER + 2
    s = status(gw)
    d = devices(s)[SILENT]
    assert (d["health"], d["consecutive_failures"]) == ("degraded", DOWN_AFTER + 2)
    assert d["demoted_rejects"] == s["counters"]["demoted_rejects"] == 0
    assert "is down" not in gw.log()


def config_set(path, *words: str) -> None:
    result = mbgw("config", "set", "--config", str(path), *words)
    assert result.returncode == 0, result.stderr


def test_a_reload_applies_down_after_and_probe_interval_without_reopening_the_line(
        pty_pair, recording_peer, start_gateway, tmp_path, client):
    """down-after 0 in the file: a silent address stays up for the line.  The file then says
    down-after 2: on SIGHUP the address, 3 failures in a row already, is down at once, and
    the same connection's next request is refused; the line was never reopened."""
    record = recording_peer("fault_slave.py")
    path = tmp_path / "mbgw.toml"
    for words in (("baudrate", "38400"), ("stout", str(STOUT_MS)), ("down-after", "0")):
        config_set(path, "serial", *words)
    config_set(path, "net", "exception", "on")
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    asker = Asker(client(gw), exception=True)
    for _ in range(3):
        assert asker.ask(SILENT) == NO_ANSWER
    config_set(path, "serial", "down-after", str(DOWN_AFTER))
    config_set(path, "serial", "probe-interval", "60000")
    os.kill(gw.proc.pid, signal.SIGHUP)
    log = wait_for_log(gw, "configuration reloaded: demotion.down_after, "
                           "demotion.probe_interval_ms changed")
    assert f"device {SILENT} is down: 3 requests in a row without a valid reply; its " \
           f"requests are refused, but for a probe every 60 s" in log
    assert asker.ask(SILENT) == NO_ANSWER
    assert len(on_line(record, SILENT)) == 3
    assert devices(status(gw))[SILENT]["demoted_rejects"] == 1
    assert "reopening" not in gw.log()


# --- master mode ----------------------------------------------------------------------------

HOST, OTHER_HOST = "127.0.9.6", "127.0.9.7"
ADDRESS, OTHER = 6, 7        # the serial addresses, sent upstream as units 6 and 7
TCPTO_MS = 200


def answer(address: int) -> bytes:
    """The server's reply to serial_read(address) (3 registers from 0), as the line gets it."""
    return bytes((address,)) + read_reply(address, 0, 3)


def refused(address: int) -> bytes:
    return bytes((address, 0x83, 0x0B))


def silent(tid: int, unit: int, start: int, count: int) -> bytes:
    return b""


def exception_02(tid: int, unit: int, start: int, count: int) -> bytes:
    return server_mbap(tid, unit, bytes.fromhex("83 02"))


@pytest.fixture
def servers():
    """(the server of ADDRESS, scripted; the server of OTHER, always answering)."""
    started = [ScriptedServer(HOST, free_port())]
    started.append(ScriptedServer(OTHER_HOST, started[0].port))
    yield started
    for s in started:
        s.stop()


@pytest.fixture
def master(servers, start_master):
    """master(*options) -> `mbgw master`: ADDRESS -> HOST, OTHER -> OTHER_HOST, tcpto
    TCPTO_MS, demoted after DOWN_AFTER failures and probed every INTERVAL_MS unless told."""
    def start(*options: str):
        return start_master("--mdbport", str(servers[0].port),
                            "--slaveid", f"{ADDRESS} {ADDRESS} {ADDRESS} 0 {HOST}",
                            "--slaveid", f"{OTHER} {OTHER} {OTHER} 0 {OTHER_HOST}",
                            "--tcpto", str(TCPTO_MS), "--down-after", str(DOWN_AFTER),
                            "--probe-interval", str(INTERVAL_MS), *options)
    return start


def read(address: int) -> bytes:
    return serial_read(address, count=3)


def assert_probes_respect_their_windows(arrivals: list[float]) -> None:
    """The requests after the DOWN_AFTER-th are probes: each at least the interval (doubled
    after each failed probe) after the one before it."""
    failed_at = arrivals[DOWN_AFTER - 1]
    for n, probe in enumerate(arrivals[DOWN_AFTER:]):
        assert probe - failed_at >= INTERVAL_S * 2 ** n, (n, arrivals)
        failed_at = probe


def test_master_a_silent_server_takes_its_address_down_probes_and_back(master, servers, line):
    """ADDRESS's server does not answer 4 requests: 2 make the address down; the serial
    master then gets 0x0B at once for each request but the probes, which reach the server at
    the windows; the third probe is answered, and the address serves again."""
    server = servers[0]
    server.faults.extend([silent] * (DOWN_AFTER + 2))
    gw = master("--exception")
    for _ in range(DOWN_AFTER):
        ask(line, read(ADDRESS), expected=refused(ADDRESS))
    ask(line, read(ADDRESS), expected=refused(ADDRESS))     # down: nothing to the server
    assert len(server.requests) == DOWN_AFTER
    refusals = 1 + probed_on_line(line, read(ADDRESS), answer(ADDRESS), refused(ADDRESS))
    ask(line, read(ADDRESS), expected=answer(ADDRESS))
    assert len(server.requests) == DOWN_AFTER + 4 and not server.faults
    assert_probes_respect_their_windows(server.arrivals[:DOWN_AFTER + 3])

    s = status(gw)
    d = devices(s)[ADDRESS]
    failed = DOWN_AFTER + 2
    assert (d["health"], d["timeouts"], d["replies"]) == ("degraded", failed, 2)
    # the probes that failed were answered 0x0B too, not counted refused
    assert d["demoted_rejects"] == s["counters"]["demoted_rejects"] == refusals - 2
    assert d["transactions"] == len(server.requests)
    assert d["gateway_exceptions"] == {"0x0b": failed + refusals - 2}
    assert health_log(gw, ADDRESS) == ["degraded", "down", "degraded"]
    assert f"device {ADDRESS} is down: {DOWN_AFTER} requests in a row without a valid reply " \
           f"(server {HOST} unit {ADDRESS}); its requests are refused" in gw.log()
    assert s["counters"]["requests"] == len(server.requests) + refusals - 2


def test_master_without_exception_a_down_address_gets_no_answer(master, servers, line):
    server, other = servers
    server.faults.extend([silent] * (DOWN_AFTER + 1))
    gw = master()
    for _ in range(DOWN_AFTER + 1):
        unanswered(line, read(ADDRESS), then=read(OTHER), expected=answer(OTHER))
    assert len(server.requests) == DOWN_AFTER
    assert len(other.requests) == DOWN_AFTER + 1
    sent = DOWN_AFTER + 1
    deadline = time.monotonic() + GIVE_UP_S
    while len(server.requests) == DOWN_AFTER:       # until the probe (it fails: no answer)
        unanswered(line, read(ADDRESS), then=read(OTHER), expected=answer(OTHER))
        sent += 1
        assert time.monotonic() < deadline, "no probe"
    assert len(server.requests) == DOWN_AFTER + 1
    assert_probes_respect_their_windows(server.arrivals)
    d = devices(status(gw))[ADDRESS]
    assert d["demoted_rejects"] == sent - len(server.requests)
    assert d["gateway_exceptions"] == {} and d["health"] == "down"


def test_master_a_server_that_answers_with_an_exception_keeps_its_address_up(master, servers,
                                                                              line):
    server = servers[0]
    server.faults.extend([exception_02] * (3 * DOWN_AFTER))
    gw = master("--exception")
    for _ in range(3 * DOWN_AFTER):
        ask(line, read(ADDRESS), expected=bytes((ADDRESS, 0x83, 0x02)))
    assert len(server.requests) == 3 * DOWN_AFTER
    d = devices(status(gw))[ADDRESS]
    assert (d["health"], d["demoted_rejects"]) == ("up", 0)


def test_master_down_after_0_never_demotes(master, servers, line):
    server = servers[0]
    server.faults.extend([silent] * (DOWN_AFTER + 2))
    gw = master("--exception", "--down-after", "0")
    for _ in range(DOWN_AFTER + 2):
        ask(line, read(ADDRESS), expected=refused(ADDRESS))
    assert len(server.requests) == DOWN_AFTER + 2
    d = devices(status(gw))[ADDRESS]
    assert (d["health"], d["demoted_rejects"]) == ("degraded", 0)


def test_master_a_reload_applies_down_after_without_reopening_the_line(servers, start_master,
                                                                       line, tmp_path):
    server = servers[0]
    server.faults.extend([silent] * 3)
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\nmode = "master"\nbaudrate = 19200\ndown-after = 0\n\n[net]\n'
                    f'slaveid = ["{ADDRESS} {ADDRESS} {ADDRESS} 0 {HOST}"]\n'
                    f'mdbport = {server.port}\ntcpto = {TCPTO_MS}\nexception = true\n')
    gw = start_master("--config", str(path))
    for _ in range(3):
        ask(line, read(ADDRESS), expected=refused(ADDRESS))
    config_set(path, "serial", "down-after", str(DOWN_AFTER))
    config_set(path, "serial", "probe-interval", "60000")
    os.kill(gw.proc.pid, signal.SIGHUP)
    log = wait_for_log(gw, "configuration reloaded: demotion.down_after, "
                           "demotion.probe_interval_ms changed")
    assert f"device {ADDRESS} is down: 3 requests in a row" in log
    ask(line, read(ADDRESS), expected=refused(ADDRESS))
    assert len(server.requests) == 3
    assert devices(status(gw))[ADDRESS]["demoted_rejects"] == 1
    assert "reopening" not in gw.log()
