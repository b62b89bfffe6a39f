"""SIGHUP (systemctl reload) in master mode: the configuration file is applied again without a
restart (the slaveid table, tcpto, exception, max-connections), new line settings reopen the
line, and a bad file is refused while the gateway keeps serving.  The file is changed the way
an operator does it, with `mbgw config set`; each reload is awaited on the daemon's log."""
import os
import signal
import time

import pytest

from tests.integration.master.rig import (
    ask,
    holding_reply,
    identity,
    mbgw,
    read_holding,
    status,
    stop_counters,
    unanswered,
    wait_for,
    wait_for_log,
)

pytestmark = pytest.mark.integration

ONE, TWO = "127.0.7.1", "127.0.7.2"     # servers that answer
SILENT = "127.0.7.3"                     # accepts connections, never answers
ABSENT = "127.0.7.9"                     # nobody listens
SLOW_TCPTO_MS = 3000                     # the first tcpto; a reload brings it to FAST
FAST_TCPTO_MS = 200


def reply(address: int, host: str, unit: int) -> bytes:
    return holding_reply(address, *identity(host, unit))


def exception(address: int, code: int) -> bytes:
    return bytes((address, 0x83, code))


def config_set(path, *words: str) -> None:
    result = mbgw("config", "set", "--config", str(path), *words)
    assert result.returncode == 0, result.stderr


def reload(gw, expected: str, count: int = 1) -> str:
    os.kill(gw.proc.pid, signal.SIGHUP)
    return wait_for_log(gw, expected, count)


@pytest.fixture
def setup(tmp_path, servers_at, start_master):
    """A master-mode file (address 1 -> ONE unit 1; 3 -> SILENT; 4 -> ABSENT; tcpto
    SLOW_TCPTO_MS, exception off) and a gateway started from it, the device given on the
    command line."""
    port, _ = servers_at(ONE, TWO, silent=[SILENT])
    path = tmp_path / "mbgw.toml"
    path.write_text(f'[serial]\nmode = "master"\nbaudrate = 19200\n\n[net]\n'
                    f'slaveid = ["1 1 1 0 {ONE}", "3 3 1 0 {SILENT}", "4 4 1 0 {ABSENT}"]\n'
                    f'mdbport = {port}\ntcpto = {SLOW_TCPTO_MS}\n')
    gw = start_master("--config", str(path))
    return gw, path


def test_a_new_slaveid_table_applies_on_sighup(setup, line):
    gw, path = setup
    ask(line, read_holding(1), expected=reply(1, ONE, 1))
    unanswered(line, read_holding(2), then=read_holding(1), expected=reply(1, ONE, 1))
    reload(gw, "configuration reloaded: nothing changed")

    config_set(path, "net", "slaveid", "1", "1", "9", "0", TWO)      # replaces 1..1
    config_set(path, "net", "slaveid", "2", "2", "5", "0", ONE)      # a new range
    reload(gw, "configuration reloaded: slaveid changed")
    ask(line, read_holding(1), expected=reply(1, TWO, 9))
    ask(line, read_holding(2), expected=reply(2, ONE, 5))
    routes = [r["route"] for r in status(gw)["slaveid"]]
    assert routes == [f"3..3 -> {SILENT} unit 1", f"4..4 -> {ABSENT} unit 1",
                      f"1..1 -> {TWO} unit 9", f"2..2 -> {ONE} unit 5"]
    assert gw.proc.poll() is None


@pytest.mark.serial
def test_tcpto_exception_and_max_connections_apply_on_sighup(setup, line):
    gw, path = setup
    ask(line, read_holding(1), expected=reply(1, ONE, 1))
    # exception off: the unreachable server's request gets no answer (and none was made)
    unanswered(line, read_holding(4), then=read_holding(1), expected=reply(1, ONE, 1))
    config_set(path, "net", "slaveid", "2", "2", "1", "0", TWO)
    reload(gw, "configuration reloaded: slaveid changed")
    ask(line, read_holding(2), expected=reply(2, TWO, 1))
    before = status(gw)
    assert (before["counters"]["unreachable"], before["counters"]["gateway_exceptions"]) == \
        (1, 0)
    assert len(before["upstream"]["connections"]) == 2

    config_set(path, "net", "exception", "on")
    config_set(path, "net", "tcpto", str(FAST_TCPTO_MS))
    config_set(path, "net", "max-connections", "1")
    reload(gw, "configuration reloaded: tcpto_ms, exception, max_connections changed")
    ask(line, read_holding(4), expected=exception(4, 0x0A))
    started = time.monotonic()
    ask(line, read_holding(3), expected=exception(3, 0x0B))
    assert time.monotonic() - started < SLOW_TCPTO_MS / 1000 / 2     # not the old tcpto
    s = wait_for(gw, lambda s: s["counters"]["replies"] == 5, "counted the 0x0b")
    assert s["upstream"] | {"connections": None} == {
        "port": s["upstream"]["port"], "tcpto_ms": FAST_TCPTO_MS, "exception": True,
        "max_connections": 1, "connections": None}
    assert [c["server"].split(":")[0] for c in s["upstream"]["connections"]] == [SILENT]
    counters = stop_counters(gw)
    assert (counters["timeouts"], counters["gateway_exceptions"]) == (1, 2)
    # ONE made room when the limit came down to 1, TWO when ABSENT was tried (the limit
    # counts a connection being made)
    assert (counters["connections_opened"], counters["connections_evicted"]) == (3, 2)


def test_a_bad_file_is_refused_and_the_gateway_keeps_serving(setup, line):
    gw, path = setup
    path.write_text(path.read_text().replace(f"tcpto = {SLOW_TCPTO_MS}", "tcpto = 0"))
    log = reload(gw, "reload refused, the running configuration stays")
    assert "net.tcpto" in log.split("reload refused")[1].splitlines()[0]
    ask(line, read_holding(1), expected=reply(1, ONE, 1))
    assert status(gw)["upstream"]["tcpto_ms"] == SLOW_TCPTO_MS
    path.write_text(path.read_text().replace("slaveid = [", "slaveid = [\"9 1 1 0 1.2.3.4\", "))
    log = reload(gw, "reload refused, the running configuration stays", count=2)
    assert "net.slaveid[1]" in log.split("reload refused")[2].splitlines()[0]
    ask(line, read_holding(1), expected=reply(1, ONE, 1))


def test_new_line_settings_reopen_the_line(setup, line):
    gw, path = setup
    ask(line, read_holding(1), expected=reply(1, ONE, 1))
    config_set(path, "serial", "format", "8e1")
    config_set(path, "serial", "baudrate", "38400")     # the command line's 19200 wins
    reload(gw, "configuration reloaded: serial.format changed\n")
    wait_for_log(gw, "serial line settings changed: reopening")
    wait_for_log(gw, "is back")
    ask(line, read_holding(1), expected=reply(1, ONE, 1))
    s = status(gw)
    assert (s["serial"]["format"], s["serial"]["baudrate"], s["serial"]["state"]) == \
        ("8e1", 19200, "up")
