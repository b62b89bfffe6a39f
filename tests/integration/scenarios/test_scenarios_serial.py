"""Serial scenarios in slave mode (issue 15): the gateway polls serial slaves into the exchange
table and writes table data out to them on its own, sharing the line fairly with the TCP
clients' direct messaging.  Peers that are not ours: pymodbus's RTU server, and the scripted
fault peer (tests/peers/fault_slave.py), whose record of the frames it received tells the order
things went on the line -- no wall-clock windows.

Expected values come from the peers: pymodbus's holding register n holds 100 + n and input
register n 1000 + n; the fault peer's registers i hold 1000 + i, and its behaviour is chosen by
the serial address (2 silent, 7 the wrong function, 11 exception 02, 14 silent to its first
requests, 16 one register short).  VPGate's messages are the issue's.  The table answers units
247-254 (the default); unit 247, register R is table register R.
"""
import json
import os
import select
import signal
import termios
import time

import pytest
from prometheus_client import parser

from tests.harness import free_port
from tests.integration.slave.test_diagnostics import scrape
from tests.integration.slave.test_faults import received
from tests.modbus import Client, holding_reply, read_holding, rtu
from tests.ops import mbgw, metric_families, metric_value, status, wait_for, wait_for_log
from tests.wait import until

pytestmark = pytest.mark.integration

TABLE_UNIT = 247
WAIT_S = 10.0               # for what the gateway does on its own (many scenario runs)
# Tests of a scenario's own errors: its device is never demoted (tests/integration/
# test_scenarios_demotion.py has demotion), so that every run goes on the line.
NEVER_DOWN = {"down-after": 0}


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def write_config(path, scenarios: list[dict], baudrate: int = 115200, stout: int = 100,
                 metrics: str | None = None, serial: dict | None = None, **table) -> None:
    """A configuration file with these [[scenario]] tables (keys as in the file); serial:
    more keys of [serial]."""
    lines = ["[serial]", 'mode = "slave"', f"baudrate = {baudrate}", f"stout = {stout}",
             *(f"{k} = {toml_value(v)}" for k, v in (serial or {}).items()),
             "[net]", "exception = true"]
    if metrics:
        lines += ["[general]", f'metrics = "{metrics}"']
    if table:
        lines += ["[table]"] + [f"{k} = {toml_value(v)}" for k, v in table.items()]
    for scenario in scenarios:
        lines.append("[[scenario]]")
        lines += [f"{key} = {toml_value(value)}" for key, value in scenario.items()]
    path.write_text("\n".join(lines) + "\n")


def poll(name: str, slave: int, function: int, address: int, quantity: int, table: int,
         cycle: int = 100, **more) -> dict:
    return {"name": name, "slave": slave, "function": function, "address": address,
            "quantity": quantity, "table": table, "cycle": cycle, **more}


def on_change(name: str, slave: int, function: int, address: int, table: int, **more) -> dict:
    return {"name": name, "slave": slave, "function": function, "address": address,
            "quantity": 1, "table": table, "trigger": "change", **more}


@pytest.fixture
def gateway(tmp_path, pty_pair, start_gateway):
    """gateway(scenarios, **config) -> the gateway with these scenarios (the peer must be
    started first), and its configuration file's path."""
    def start(scenarios: list[dict], **config):
        path = tmp_path / "mbgw.toml"
        write_config(path, scenarios, **config)
        return start_gateway(pty_pair.gateway, "--config", str(path)), path
    return start


@pytest.fixture
def pymodbus_line(pty_pair, start_peer):
    def start(*addresses: int) -> None:
        start_peer("pymodbus_slave.py", pty_pair.device, *map(str, addresses),
                   "--silent-unknown")
    return start


@pytest.fixture
def fault_line(recording_peer):
    """fault_line(*options) -> the record of the fault peer's frames."""
    def start(*options: str):
        return recording_peer("fault_slave.py", *options)
    return start


def table_read(client: Client, first: int, count: int) -> bytes:
    return client.ask(TABLE_UNIT, read_holding(first, count))


def scenarios_by_name(s: dict) -> dict[str, dict]:
    return {sc["name"]: sc for sc in s.get("scenarios", [])}


def wait_for_scenario(gw, name: str, condition, what: str) -> dict:
    return scenarios_by_name(wait_for(gw, lambda s: name in scenarios_by_name(s) and
                                      condition(scenarios_by_name(s)[name]), what))[name]


def frames_to(record, address: int) -> list[bytes]:
    return [f for _, f in received(record) if f[0] == address]


# --- polling devices into the table ---

def test_two_devices_polled_into_the_table_are_read_in_one_request(pymodbus_line, gateway,
                                                                  client):
    """README's example: two serial slaves' registers side by side in the table."""
    pymodbus_line(1, 2)
    port = free_port()
    gw, _ = gateway([poll("boiler", 1, 3, 0, 10, 0), poll("meter", 2, 4, 5, 10, 10)],
                    metrics=f"127.0.0.1:{port}")
    c = client(gw)
    want = holding_reply(0, 0)[:1] + bytes((40,)) + b"".join(
        v.to_bytes(2, "big") for v in [*range(100, 110), *range(1005, 1015)])
    until(lambda: table_read(c, 0, 20) == want, "both devices' data in the table", WAIT_S)
    s = wait_for_scenario(gw, "meter", lambda sc: sc["state"] == "running", "meter running")
    assert s["message"] == "" and s["successes"] >= 1
    families = metric_families(parser, scrape(port)[2])
    assert metric_value(families, "mbgw_scenario_runs", "mbgw_scenario_runs_total",
                        scenario="meter") >= s["runs"]
    assert metric_value(families, "mbgw_scenario_state", scenario="boiler",
                        state="running") == 1


def test_a_value_is_copied_from_one_device_to_another_on_change(pymodbus_line, gateway,
                                                               client):
    """Device 1's register 0 is read into table 50; a change scenario writes table 50 to
    device 2's register 5 (FC 6) whenever the value changes, whoever changed it."""
    pymodbus_line(1, 2)
    gw, _ = gateway([poll("source", 1, 3, 0, 1, 50),
                     on_change("copy", 2, 6, 5, 50)])
    c = client(gw)
    until(lambda: c.ask(2, read_holding(5, 1)) == bytes.fromhex("03 02 0064"),
          "device 1's 100 copied to device 2", WAIT_S)
    assert c.ask(1, bytes.fromhex("06 0000 1092")) == bytes.fromhex("06 0000 1092")
    until(lambda: c.ask(2, read_holding(5, 1)) == bytes.fromhex("03 02 1092"),
          "device 1's new value copied to device 2", WAIT_S)


# --- the change trigger and the insertion order, from the frames the peer saw ---

def test_the_same_value_again_sends_nothing_a_new_value_one_write(fault_line, gateway, client):
    """stout 1 s: a reply slowed by a loaded host must not make a write sent again (a retry,
    or an unanswered write owed) and count twice."""
    record = fault_line()
    gw, _ = gateway([on_change("out", 20, 6, 7, 300)], stout=1000)
    c = client(gw)
    for value in (5, 5, 6):
        assert c.ask(TABLE_UNIT, bytes.fromhex(f"06 012c {value:04x}"))[0] == 0x06
        if value == 5:
            until(lambda: frames_to(record, 20), "the first write", WAIT_S)
    until(lambda: len(frames_to(record, 20)) >= 2, "the second write", WAIT_S)
    # a request on the line behind anything the writes could still have queued
    assert c.ask(21, read_holding(0, 1)) == holding_reply(0, 1)
    assert [f[1:6] for f in frames_to(record, 20)] == [bytes.fromhex("06 0007 0005"),
                                                       bytes.fromhex("06 0007 0006")]


def test_a_broadcast_scenario_is_sent_to_address_0_and_awaits_no_reply(fault_line, gateway,
                                                                       client):
    """slave = 0: the write goes to every device, none answers, and that is success."""
    record = fault_line()
    gw, _ = gateway([on_change("all", 0, 6, 9, 310)])
    c = client(gw)
    assert c.ask(TABLE_UNIT, bytes.fromhex("06 0136 002a"))[0] == 0x06       # table 310 = 42
    until(lambda: frames_to(record, 0), "the broadcast", WAIT_S)
    s = wait_for_scenario(gw, "all", lambda sc: sc["runs"] == 1, "run once")
    assert (s["state"], s["successes"], s["errors"]) == ("running", 1, {}), s
    assert [f[1:6] for f in frames_to(record, 0)] == [bytes.fromhex("06 0009 002a")]


def test_pending_change_scenarios_go_between_the_cyclic_ones(fault_line, gateway, client):
    """Three cyclic scenarios that keep the line busy (address 2 never answers: each run
    lasts stout), then two change scenarios made pending by one table write: the first goes
    right after the cyclic run in progress, the second after one more cyclic run."""
    record = fault_line()
    cyclic = [poll(f"c{n}", 2, 3, n, 1, 1000 + n, retries=0) for n in range(3)]
    gw, _ = gateway([*cyclic, on_change("w1", 21, 6, 1, 400), on_change("w2", 22, 6, 2, 401)],
                    serial=NEVER_DOWN)
    c = client(gw)
    until(lambda: len(frames_to(record, 2)) >= 3, "the cyclic scenarios running", WAIT_S)
    triggered = time.monotonic()
    assert c.ask(TABLE_UNIT, bytes.fromhex("10 0190 0002 04 0001 0002"))[0] == 0x10
    until(lambda: frames_to(record, 22), "the second change scenario", WAIT_S)
    after = [f[0] for when, f in received(record) if when >= triggered]
    w1, w2 = after.index(21), after.index(22)
    assert w1 <= 1, after                       # at most the cyclic run being started
    assert after[w1 + 1:w2] == [2], after       # one cyclic run between the two


# --- errors, retries and recovery against the fault peer ---

ERRORS = {
    "silent": (2, "timeout, no answer from slave after retrying"),
    "exception": (11, "received illegal data address from slave (0x02)"),
    "wrong-function": (7, "received unexpected function in answer"),
    "wrong-quantity": (16, "received unexpected data/quantity in answer"),
}


def test_failing_devices_put_their_scenarios_in_error_with_vpgates_messages(fault_line,
                                                                           gateway):
    record = fault_line()
    gw, _ = gateway([poll(name, slave, 3, 0, 4, 10 * n, cycle=200, retries=1)
                     for n, (name, (slave, _)) in enumerate(ERRORS.items())], serial=NEVER_DOWN)
    for name, (_, message) in ERRORS.items():
        s = wait_for_scenario(gw, name, lambda sc: sc["runs"] >= 2, f"{name} run twice")
        assert (s["state"], s["message"]) == ("error", message), s
        assert s["successes"] == 0
    s = scenarios_by_name(status(gw))
    # a timeout and a dropped reply are retried (retries = 1), an exception is an answer
    assert s["silent"]["retries"] >= s["silent"]["runs"] - 1 >= 1
    assert s["wrong-function"]["retries"] >= 1
    assert s["exception"]["retries"] == 0
    silent = frames_to(record, 2)
    assert len(silent) >= 2 and len(set(silent)) == 1     # the request and its retry
    log = gw.log()
    for name in ERRORS:
        assert log.count(f"scenario {name} ") == 1, log      # entering error: logged once


def test_a_scenario_recovers_when_its_device_answers_again(fault_line, gateway, client):
    record = fault_line("--mute-first", "3")
    gw, _ = gateway([poll("late", 14, 3, 0, 2, 60, retries=0)], serial=NEVER_DOWN)
    wait_for_scenario(gw, "late", lambda sc: sc["state"] == "error", "in error")
    s = wait_for_scenario(gw, "late", lambda sc: sc["state"] == "running", "running again")
    assert s["errors"] == {"timeout": 3} and s["successes"] >= 1
    assert table_read(client(gw), 60, 2) == holding_reply(0, 2)
    assert frames_to(record, 14)[:4] == [frames_to(record, 14)[0]] * 4
    log = wait_for_log(gw, "running again")
    assert log.count("scenario late (") == 2, log      # entering and leaving error, once each


# --- direct messaging beside 100 scenarios ---

@pytest.mark.serial
def test_a_client_is_served_while_100_scenarios_saturate_the_line(fault_line, gateway, client):
    """100 scenarios due every 100 ms want more than the line can carry; a client asking
    one request at a time gets every reply, and the line alternates: a scenario run
    between two of its requests, never a run of scenarios that starves it."""
    record = fault_line()
    gw, _ = gateway([poll(f"s{n:03d}", 30, 3, n, 10, 10 * n) for n in range(100)],
                    baudrate=19200)
    c = client(gw)
    until(lambda: len(frames_to(record, 30)) >= 10, "the scenarios running", WAIT_S)
    for n in range(20):
        assert c.ask(31, read_holding(n, 2)) == holding_reply(n, 2)
    until(lambda: len(frames_to(record, 31)) == 20 and received(record)[-1][1][0] == 30,
          "a scenario run after the last request", WAIT_S)
    order = [f[0] for _, f in received(record)]
    first = order.index(31)
    gaps = [len(run) for run in bytes(order[first:]).split(bytes((31,)))[1:-1]]
    assert gaps and all(1 <= gap <= 2 for gap in gaps), gaps


# --- reload, enable and disable ---

def test_reload_adds_and_removes_scenarios_and_keeps_the_unchanged_ones(fault_line, gateway,
                                                                      client):
    record = fault_line()
    kept = poll("kept", 40, 3, 0, 1, 0)
    gw, path = gateway([kept, poll("gone", 41, 3, 0, 1, 1)])
    before = wait_for_scenario(gw, "kept", lambda sc: sc["runs"] >= 3, "kept running")
    write_config(path, [kept, poll("new", 42, 3, 0, 1, 2)])
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded")
    assert client(gw).ask(43, read_holding(0, 1)) == holding_reply(0, 1)   # a marker frame
    until(lambda: len(frames_to(record, 42)) >= 3, "the new scenario running", WAIT_S)
    order = [f[0] for _, f in received(record)]
    assert 41 not in order[order.index(43):], order
    s = scenarios_by_name(status(gw))
    assert set(s) == {"kept", "new"}
    assert s["kept"]["runs"] > before["runs"]           # its counters went on


def test_disable_stops_a_scenario_until_it_is_enabled_again(fault_line, gateway, client):
    """`mbgw scenario disable NAME`: no more of its frames on the line (told from a marker
    request sent after the command), the other goes on; enable: it runs again."""
    record = fault_line()
    gw, path = gateway([poll("a", 50, 3, 0, 1, 0), poll("b", 51, 3, 0, 1, 1)])
    until(lambda: len(frames_to(record, 50)) >= 2, "a running", WAIT_S)
    done = mbgw("scenario", "disable", "a", "--control", gw.control)
    assert done.returncode == 0, done.stderr
    c = client(gw)
    assert c.ask(52, read_holding(0, 1)) == holding_reply(0, 1)       # a marker frame
    marker = len(received(record))
    until(lambda: len(frames_to(record, 51)) >= len(frames_to(record, 50)) + 5,
          "b going on", WAIT_S)
    assert 50 not in [f[0] for _, f in received(record)[marker:]]
    assert scenarios_by_name(status(gw))["a"]["state"] == "disabled"
    assert 'enabled = false' not in path.read_text()                   # not --save
    done = mbgw("scenario", "enable", "a", "--control", gw.control)
    assert done.returncode == 0, done.stderr
    count = len(frames_to(record, 50))
    until(lambda: len(frames_to(record, 50)) > count, "a running again", WAIT_S)


def test_scenario_test_runs_once_on_the_line_and_changes_nothing(fault_line, gateway, client):
    """`mbgw scenario test`, on a gateway with no scenario at all: the request goes on the
    line once, the data is printed, the table is left alone."""
    record = fault_line()
    gw, _ = gateway([], enabled=True)
    done = mbgw("scenario", "test", "slave=60", "function=3", "address=4", "quantity=2",
                "table=80", "--json", "--control", gw.control)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["ok"] and result["data"] == [1004, 1005], result
    assert frames_to(record, 60) == [bytes.fromhex("3c 03 0004 0002") +
                                     frames_to(record, 60)[0][-2:]]
    assert table_read(client(gw), 80, 2) == bytes.fromhex("03 04 0000 0000")
    # a read needs no table: its data is printed, not stored
    done = mbgw("scenario", "test", "slave=61", "function=3", "address=7", "quantity=1",
                "--control", gw.control)
    assert done.returncode == 0, done.stderr
    assert "data     (1 from 7)\n   1007" in done.stdout, done.stdout
    assert frames_to(record, 61)[0][:6] == bytes.fromhex("3d 03 0007 0001")
    assert table_read(client(gw), 0, 1) == bytes.fromhex("03 02 0000")
    done = mbgw("scenario", "test", "slave=11", "function=3", "address=0", "quantity=1",
                "table=0", "--json", "--control", gw.control)
    result = json.loads(done.stdout)
    assert not result["ok"]
    assert result["message"] == "received illegal data address from slave (0x02)"


# --- stale data ---

def test_stale_data_answers_0x0b_until_the_device_answers_again(fault_line, gateway, client):
    """Device 14 is silent to its first 8 requests: the scenario's range is stale (a TCP read
    touching it gets 0x0B, one beside it does not) until the device answers."""
    fault_line("--mute-first", "8")
    gw, _ = gateway([poll("fresh", 14, 3, 0, 2, 70, retries=0, **{"stale-after": 300})],
                    serial=NEVER_DOWN)
    c = client(gw)
    until(lambda: table_read(c, 71, 1) == bytes.fromhex("83 0b"), "stale data refused", WAIT_S)
    assert table_read(c, 72, 1) == bytes.fromhex("03 02 0000")       # beside the range
    until(lambda: table_read(c, 70, 2) == holding_reply(0, 2), "fresh data again", WAIT_S)


# --- the device lost and back ---

def test_a_change_made_while_the_device_is_lost_is_written_once_it_is_back(
        pty_pair, pymodbus_line, gateway, client):
    """Nothing runs while the device is lost (a scenario test says so at once); a change of
    the data a change scenario writes is kept, and sent when the device is back.  The port
    comes back before its peer does: the write is then sent and not answered, and stays owed
    (the device demoted meanwhile: the probes of this test's reads, every probe-interval)."""
    pymodbus_line(1, 2)
    gw, _ = gateway([poll("keepalive", 1, 3, 0, 1, 0), on_change("out", 2, 6, 6, 60)],
                    serial={"probe-interval": 200})
    c = client(gw)
    wait_for_scenario(gw, "keepalive", lambda sc: sc["successes"] >= 1, "running")
    pty_pair.stop()                             # the device disappears
    wait_for_log(gw, "lost")
    assert c.ask(TABLE_UNIT, bytes.fromhex("06 003c 0309"))[0] == 0x06      # table 60 = 777
    done = mbgw("scenario", "test", "slave=1", "function=3", "address=0", "quantity=1",
                "table=0", "--json", "--control", gw.control)
    assert json.loads(done.stdout)["message"] == "gateway path unavailable (0x0A)", done.stdout
    pty_pair.start()
    pymodbus_line(1, 2)
    until(lambda: c.ask(2, read_holding(6, 1)) == bytes.fromhex("03 02 0309"),
          "the change written once the device is back", WAIT_S)


def test_the_table_the_scenarios_serve_is_shown_on_and_the_start_names_file_and_scenarios(
        fault_line, gateway, client):
    """table.enabled off, but scenarios run: status and config show say the table is on for
    them; the start-up line names the file, the table and the scenarios."""
    fault_line()
    gw, path = gateway([poll("a", 50, 3, 0, 2, 0), poll("b", 51, 3, 0, 1, 1)])
    wait_for_scenario(gw, "b", lambda sc: sc["runs"] > 0, "b running")
    assert "WARNING mbgw: scenario b: stores into table registers 1, as scenario a does: " \
           "each overwrites the other's data" in gw.log(), gw.log()
    shown = mbgw("status", "--control", gw.control)
    assert "table      on (scenarios): no Modbus client reaches it" in shown.stdout, shown.stdout
    assert "table      off" not in shown.stdout
    config = mbgw("config", "show", "table", "--config", str(path))
    assert config.returncode == 0, config.stderr
    assert "enabled          on (scenarios)" in config.stdout, config.stdout
    assert f"; configuration {path}; table on (scenarios); scenarios a, b" in gw.log()


# --- VPGate's "Slave not responding, retrying..." while a run retries -------------------------

@pytest.fixture
def raw_line(line):
    """The device end of the line (the fd of the line fixture) in raw mode: bytes as written,
    none echoed."""
    attrs = termios.tcgetattr(line)
    attrs[0] = attrs[1] = attrs[3] = 0
    termios.tcsetattr(line, termios.TCSANOW, attrs)
    return line


def _request_on(fd: int, length: int = 8) -> bytes:
    data = b""
    while len(data) < length:
        ready, _, _ = select.select([fd], [], [], WAIT_S)
        assert ready, f"no request on the line, got {data.hex(' ')!r}"
        data += os.read(fd, length - len(data))
    return data


def test_a_run_that_retries_says_slave_not_responding_retrying(raw_line, gateway):
    """The device (this test, on the line) lets the first request go unanswered: the retry is
    on the wire, the scenario says VPGate's "retrying"; answered, the message goes."""
    fd = raw_line
    gw, _ = gateway([poll("pump", 5, 3, 0, 1, 100, cycle=65535, retries=2)],
                    stout=300, serial=NEVER_DOWN)
    request = rtu(5, read_holding(0, 1))
    assert _request_on(fd) == request               # unanswered
    assert _request_on(fd) == request               # its retry
    s = wait_for_scenario(gw, "pump", lambda sc: sc["message"] != "", "a message")
    assert s["message"] == "slave not responding, retrying...", s
    os.write(fd, rtu(5, bytes((0x03, 2, 0x00, 0x2A))))
    s = wait_for_scenario(gw, "pump", lambda sc: sc["runs"] == 1, "the run done")
    assert (s["state"], s["message"], s["retries"]) == ("running", "", 1), s
    c = Client(gw.port)
    try:
        assert c.ask(TABLE_UNIT, read_holding(100, 1)) == bytes((0x03, 2, 0x00, 0x2A))
    finally:
        c.close()


def test_another_masters_frame_instead_of_the_reply_is_frame_received_without_request(
        raw_line, gateway):
    """VPGate 8.2: when another master talks on the line (here a request to address 9 where
    the reply of slave 5 should be), the run fails "frame received without request", not with
    a plain timeout."""
    fd = raw_line
    gw, _ = gateway([poll("pump", 5, 3, 0, 1, 100, cycle=65535, retries=0)],
                    stout=300, serial=NEVER_DOWN)
    assert _request_on(fd) == rtu(5, read_holding(0, 1))
    os.write(fd, rtu(9, read_holding(0, 1)))        # the other master's request
    s = wait_for_scenario(gw, "pump", lambda sc: sc["runs"] == 1, "the run done")
    assert (s["state"], s["message"]) == ("error", "frame received without request"), s
    assert s["errors"] == {"frame-without-request": 1}, s
