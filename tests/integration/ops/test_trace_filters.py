"""`mbgw trace` (issue 25): the serial scenarios' runs shown, marked with the scenario's
name, and the filters (--unit, --client, --function, --scenario, --line, --errors) on real
traffic: TCP clients and a polling scenario on a socat pty to the fault peer
(tests/peers/fault_slave.py: address 1 answers, 2 is silent, 11 answers exception 02).  The
pcap of a trace holds the clients' exchanges only, as before."""
import subprocess

import pytest

from tests.integration.scenarios.test_scenarios_serial import poll, write_config
from tests.modbus import holding_reply, read_holding
from tests.ops import mbgw, status, wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
def gw(tmp_path, pty_pair, recording_peer, start_gateway):
    """The fault peer, and a gateway polling its address 1's register 5 every 200 ms
    ("meter")."""
    recording_peer("fault_slave.py")
    path = tmp_path / "mbgw.toml"
    write_config(path, [poll("meter", 1, 3, 5, 1, 0, cycle=200)], stout=100,
                 serial={"retries": 0, "down-after": 0})
    return start_gateway(pty_pair.gateway, "--config", str(path))


def columns(line: str) -> list[str]:
    """TIME DIRECTION CLIENT... of a decoded line: the client's column holds "scenario
    NAME" for a scenario's run."""
    return line.replace("scenario ", "scenario:").split()


def test_scenario_runs_are_traced_with_their_name_and_filtered_by_it(gw, client, trace):
    t = trace(gw, "--scenario", "meter")
    c = client(gw)
    assert c.ask(1, read_holding(0, 1)) == holding_reply(0, 1)   # not shown
    lines = t.lines(6)[1:]
    for line in lines:
        assert columns(line)[2] == "scenario:meter", lines
    first = next(i for i, line in enumerate(lines) if columns(line)[1] == "request")
    request, reply = columns(lines[first]), columns(lines[first + 1])
    assert (request[1], request[3], request[4], request[5]) == ("request", "-", "1", "0x03")
    assert (reply[1], reply[4], reply[5], reply[7]) == ("reply", "1", "0x03", "ok"), lines


def test_unit_function_client_and_errors_filters(gw, client, trace):
    first, second = client(gw), client(gw)
    wait_for(gw, lambda s: len(s["clients"]) == 2, "both clients connected")
    ids = sorted(cl["id"] for cl in status(gw)["clients"])
    by_unit = trace(gw, "--unit", "11")
    errors = trace(gw, "--errors")
    by_client = trace(gw, "--client", str(ids[1]), "--function", "3")
    assert first.ask(11, read_holding(0, 1)) == bytes.fromhex("83 02")
    assert first.ask(2, read_holding(0, 1)) == bytes.fromhex("83 0b")
    assert second.ask(1, bytes.fromhex("06 0000 0001"))[0] == 0x06
    assert second.ask(1, read_holding(0, 1)) == holding_reply(0, 1)
    unit_lines = [columns(x) for x in by_unit.lines(3)[1:]]
    assert [(x[1], x[4]) for x in unit_lines] == [("request", "11"), ("reply", "11")]
    error_lines = [columns(x) for x in errors.lines(3)[1:]]
    assert [(x[1], x[4], x[5]) for x in error_lines] == [("reply", "11", "0x83"),
                                                          ("reply", "2", "0x83")]
    client_lines = [columns(x) for x in by_client.lines(3)[1:]]
    assert [(x[1], x[5]) for x in client_lines] == [("request", "0x03"), ("reply", "0x03")]
    assert all(x[2] == client_lines[0][2] != "scenario:meter" for x in client_lines)


def test_the_line_filter_takes_the_serial_line_only(gw, client, trace):
    t = trace(gw, "--line", "serial", "--raw")
    assert t.lines(3)[1:]            # the scenario's bursts
    wrong = mbgw("trace", "--line", "tcp", "--control", gw.control)
    # issue 24: an unknown line exits 1 naming it (it was a usage error, 2, with one line)
    assert wrong.returncode == 1 and "--line" in wrong.stderr and "tcp" in wrong.stderr, \
        wrong.stderr


def test_the_pcap_holds_the_clients_exchanges_not_the_scenarios(gw, client, tmp_path, trace):
    pcap = tmp_path / "trace.pcap"
    t = trace(gw, "--pcap", str(pcap))
    c = client(gw)
    assert c.ask(1, read_holding(0, 2)) == holding_reply(0, 2)
    lines = t.lines(7)                        # the client's two, and scenario runs
    assert any("scenario meter" in line for line in lines), lines
    t.stop()
    shown = subprocess.run(["tshark", "-r", str(pcap), "-o", f"mbtcp.tcp.port:{gw.port}",
                            "-T", "fields", "-e", "mbtcp.trans_id", "-e", "modbus.func_code"],
                           capture_output=True, text=True, timeout=60, check=True
                           ).stdout.split("\n")
    assert [x for x in shown if x] == ["1\t3", "1\t3"], shown
