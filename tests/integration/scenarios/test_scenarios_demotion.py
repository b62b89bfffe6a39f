"""Scenarios obey demotion (issue 22, point 4): while a device is down its scenario's runs are
skipped ("device down"), not put on the line, but for the probe the rule lets through; a TCP
scenario's server is judged by the same rule ("server down", not dialled but for the probe).

What went on the line is read from the peers' own records, never from mbgw's counters:
pymodbus's RTU server (tests/peers/pymodbus_slave.py --record: every request it decoded, for
any address, so also the absent slave's), the fault peer (address 14: silent to its first
--mute-first requests, then answering) and the scripted TCP server (the time of each request).
Probes are checked against the lower bounds they must respect -- each one at least the
probe interval after the failure before it, on the peers' clock (time.monotonic()) -- never
against a duration the test waited for.
"""
import pytest

from tests.integration.scenarios.test_scenarios_serial import (
    TABLE_UNIT,
    WAIT_S,
    frames_to,
    poll,
    scenarios_by_name,
    table_read,
    wait_for_scenario,
    write_config,
)
from tests.integration.scenarios.test_scenarios_tcp import scenario_status, scenario_toml
from tests.integration.slave.test_faults import received
from tests.modbus import holding_reply, read_holding
from tests.ops import devices, mbgw, status, wait_for, wait_for_log
from tests.peers.scripted_tcp_server import ScriptedServer
from tests.wait import until

pytestmark = pytest.mark.integration

STOUT_MS = 100
INTERVAL_MS = 1000            # probe-interval
INTERVAL_S = INTERVAL_MS / 1000
DOWN_AFTER = 3
RETRIES = 2                   # the scenarios' default: a run is up to 3 frames
DEMOTION = {"down-after": DOWN_AFTER, "probe-interval": INTERVAL_MS}
ABSENT = 5                    # no device answers it on the line
HEALTHY = 1                   # pymodbus: holding register n holds 100 + n
MUTED = 14                    # fault_slave: silent to its first --mute-first requests


def pymodbus_reply(start: int, count: int) -> bytes:
    return bytes((3, 2 * count)) + b"".join((100 + start + i).to_bytes(2, "big")
                                            for i in range(count))


def bursts(times: list[float]) -> list[list[float]]:
    """Frames closer than half an interval are one run (a request and its retries)."""
    out: list[list[float]] = []
    for t in times:
        if out and t - out[-1][-1] < INTERVAL_S / 2:
            out[-1].append(t)
        else:
            out.append([t])
    return out


def assert_probes_only(failed_at: float, runs: list[list[float]]) -> None:
    """Each run after the device went down (at failed_at, the last frame of the run that
    made it down) is a probe: at least an interval after the failure before it."""
    before = failed_at
    for run in runs:
        assert len(run) <= 1 + RETRIES, runs
        assert run[0] - before >= INTERVAL_S, (before, runs)
        before = run[-1]


@pytest.fixture
def gateway(tmp_path, pty_pair, start_gateway):
    def start(scenarios: list[dict]):
        path = tmp_path / "mbgw.toml"
        write_config(path, scenarios, stout=STOUT_MS, serial=DEMOTION)
        return start_gateway(pty_pair.gateway, "--config", str(path))
    return start


def test_an_absent_slaves_scenario_leaves_the_line_to_the_others_but_for_probes(
        tmp_path, pty_pair, start_peer, gateway, client):
    """The issue's case: a scenario on a switched-off slave beside a healthy one, and a TCP
    client reading the healthy slave.  Once the absent slave is down its scenario is only
    its probes on the wire, the healthy scenario runs on time, the client's reads are all
    answered by the device."""
    record = tmp_path / "wire.txt"
    start_peer("pymodbus_slave.py", pty_pair.device, str(HEALTHY), "--silent-unknown",
               "--record", str(record))
    gw = gateway([poll("meter", HEALTHY, 3, 0, 4, 0, cycle=500),
                  poll("absent", ABSENT, 3, 0, 2, 10, cycle=200)])
    wait_for(gw, lambda s: devices(s).get(ABSENT, {}).get("health") == "down", "down")
    s = wait_for_scenario(gw, "absent", lambda sc: sc["message"] == "device down",
                          "the scenario says its device is down")
    assert s["state"] == "error" and s["next_probe_in_s"] is not None, s
    shown = mbgw("scenarios", "--control", gw.control).stdout
    assert "error: device down, next probe in " in shown, shown
    meter = scenarios_by_name(status(gw))["meter"]
    c = client(gw)
    for n in range(10):
        assert c.ask(HEALTHY, read_holding(n, 2)) == pymodbus_reply(n, 2)
    until(lambda: len(frames_to(record, ABSENT)) > DOWN_AFTER * (1 + RETRIES),
          "a probe of the absent slave", WAIT_S)
    after = wait_for_scenario(gw, "meter", lambda sc: sc["successes"] >= meter["successes"] + 6,
                              "the healthy scenario going on")
    assert after["overruns"] == meter["overruns"] and after["state"] == "running", after
    assert table_read(c, 0, 4) == pymodbus_reply(0, 4)
    sent = [when for when, frame in received(record) if frame[0] == ABSENT]
    failing = DOWN_AFTER * (1 + RETRIES)          # the runs that made it down, each retried
    assert_probes_only(sent[failing - 1], bursts(sent[failing:]))
    # a probe that retries says so meanwhile ("slave not responding, retrying...")
    s = wait_for_scenario(gw, "absent", lambda sc: sc["message"] == "device down",
                          "the scenario says its device is down again after a probe")
    assert s["errors"]["device-down"] >= 1, s
    assert gw.log().count("scenario absent (") == 2, gw.log()     # timeout, then down: once


def test_a_device_that_answers_its_probe_has_its_scenario_running_again(
        recording_peer, gateway, client):
    """Device 14 is silent to its first 10 requests: three runs of 3 frames make it down;
    the line thread probes it (issue 29: with the first request that timed out, the
    scenario's, once, without retries): the probe an interval later fails, the next, twice
    the interval later, is answered; the scenario runs again at its cycle and its data is in
    the table.  (Before issue 29 the scenario's run was the probe, answered on its retry.)"""
    record = recording_peer("fault_slave.py", "--mute-first", "10")
    gw = gateway([poll("back", MUTED, 3, 0, 2, 30, cycle=200)])
    wait_for_log(gw, f"device {MUTED} is down")
    s = wait_for_scenario(gw, "back", lambda sc: sc["state"] == "running", "running again")
    assert s["errors"].get("device-down", 0) >= 1 and s["errors"]["timeout"] == DOWN_AFTER, s
    c = client(gw)
    assert table_read(c, 30, 2) == holding_reply(0, 2)
    until(lambda: len(frames_to(record, MUTED)) >= 14, "the runs after the probe", WAIT_S)
    sent = [when for when, frame in received(record) if frame[0] == MUTED]
    assert sent[9] - sent[8] >= INTERVAL_S                        # the first probe
    assert sent[10] - sent[9] >= 2 * INTERVAL_S                   # the second, answered
    assert all(b - a < INTERVAL_S for a, b in zip(sent[10:], sent[11:], strict=False)), sent
    assert c.ask(TABLE_UNIT, read_holding(30, 2)) == holding_reply(0, 2)


# --- a TCP scenario's server ---

@pytest.fixture
def scripted():
    servers = []

    def start(default: str = "ok") -> ScriptedServer:
        server = ScriptedServer((7,))
        server.default = default
        servers.append(server)
        return server
    yield start
    for server in servers:
        server.stop()


def test_a_silent_tcp_server_is_not_dialled_while_down_but_for_probes(
        tmp_path, pty_pair, start_gateway, scripted):
    """A server that accepts and never answers: after down-after timeouts it gets only probes;
    the other server's scenario (same runner, one request at a time) no longer waits behind
    tcpto each cycle; when the silent server answers its probe, its scenario runs again."""
    dead, alive = scripted("silent"), scripted()
    path = tmp_path / "mbgw.toml"
    path.write_text(
        f"[serial]\nbaudrate = 19200\ndown-after = {DOWN_AFTER}\nprobe-interval = {INTERVAL_MS}\n"
        "[net]\ntcpto = 300\n[table]\nenabled = true\n\n"
        + scenario_toml("dead", dead.server, function=3, address=0, quantity=1, table=0x1000,
                        cycle=200, retries=0)
        + scenario_toml("alive", alive.server, function=3, address=0, quantity=1,
                        table=0x1001, cycle=500))
    gw = start_gateway(pty_pair.gateway, "--config", str(path))
    wait_for_log(gw, f"scenario server {dead.server} is down")
    until(lambda: scenario_status(gw, "dead")["message"] == "server down", "server down", WAIT_S)
    before = scenario_status(gw, "alive")
    until(lambda: len(dead.times) >= DOWN_AFTER + 2, "two probes of the silent server", WAIT_S)
    after = until(lambda: (s := scenario_status(gw, "alive"))["successes"] >=
                  before["successes"] + 4 and s, "the other server's scenario going on", WAIT_S)
    assert after["overruns"] == before["overruns"], after
    times = list(dead.times)
    assert_probes_only(times[DOWN_AFTER - 1], [[t] for t in times[DOWN_AFTER:]])
    assert scenario_status(gw, "dead")["state"] == "error"
    dead.default = "ok"
    until(lambda: scenario_status(gw, "dead")["state"] == "running", "the probe answered",
          timeout=30)          # the probes' interval has doubled meanwhile
    count = len(dead.times)
    until(lambda: len(dead.times) >= count + 3, "its runs at its cycle again", WAIT_S)
