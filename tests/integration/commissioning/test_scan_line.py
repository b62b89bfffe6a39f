"""`mbgw scan --line NAME` and `mbgw probe --line NAME` through the running daemon (issue 29):
the line's thread puts one survey read on the line per turn, round robin with the clients'
requests, at the line's own settings.

The bus: pymodbus 3.16.1's RTU server (peers/pymodbus_slave.py) on a socat pty pair, units 2
and 3 (register n holds 100 + n, identity objects for FC 43/14), silent for every other
address; it records each request it decoded, so the tests see the order the line carried."""
import json
import re
import threading
import time

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from tests.integration.lines.test_lines import METER, received
from tests.integration.lines.test_lines_of_both_modes import (
    meters,  # noqa: F401 (the fixture)
    meters_line,
)
from tests.integration.master.test_serial_faces import lines_file
from tests.ops import mbgw, status
from tests.wait import until

pytestmark = pytest.mark.integration

BAUD = "19200"
IDENTITY = {"vendor": "mbgw test vendor", "product_code": "PEER-17", "revision": "3.16.1"}
CLIENT_PDU = "030000000a"     # the polling client's read: FC 3, registers 0-9 (unit 2)
REGISTER_0 = "0300000001"     # the survey's harmless read
IDENTIFY = "2b0e0100"         # FC 43/14, read code 01


@pytest.fixture
def start_daemon(tmp_path, pty_pair, start_peer, start_gateway):
    """start_daemon(*options) -> (gateway, record path): `mbgw slave` on line serial, the two
    slaves on the bus."""
    def start(*options: str):
        record = str(tmp_path / "bus.rec")
        start_peer("pymodbus_slave.py", pty_pair.device, "2", "3", "--identity",
                   "--silent-unknown", "--record", record)
        return start_gateway(pty_pair.gateway, "--baudrate", BAUD, "--stout", "1000",
                             *options), record
    return start


@pytest.fixture
def daemon(start_daemon):
    return start_daemon()


def heard(record: str) -> list[tuple[int, int, str]]:
    """(address, function, PDU hex) of each request the slaves decoded, in order."""
    rows = []
    for line in open(record):
        frame = bytes.fromhex(line.split(" rx ")[1])
        rows.append((frame[0], frame[1], frame[1:].hex()))
    return rows


class Poller(threading.Thread):
    """A pymodbus TCP client reading unit 2's registers 0-9 through the daemon until told to
    stop; every answer is checked."""

    def __init__(self, port: int) -> None:
        super().__init__()
        self.client = ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
        assert self.client.connect()
        self.stopping = threading.Event()
        self.answers = 0
        self.wrong: list = []

    def run(self) -> None:
        while not self.stopping.is_set():
            try:
                got = self.client.read_holding_registers(0, count=10, device_id=2)
            except ModbusException as err:       # no answer in time
                self.wrong.append((time.monotonic(), err))
                continue
            if got.isError() or got.registers != list(range(100, 110)):
                self.wrong.append(got)
            else:
                self.answers += 1

    def finish(self) -> None:
        if not self.stopping.is_set():
            self.stopping.set()
            self.join(10)
            self.client.close()


@pytest.fixture
def poll():
    """poll(gateway) -> a started Poller; finished after the test."""
    pollers = []

    def start(gw) -> Poller:
        pollers.append(Poller(gw.port))
        pollers[-1].start()
        return pollers[-1]
    yield start
    for poller in pollers:
        poller.finish()


# with the table on, its reader serves the clients while the line thread is on the line
@pytest.mark.parametrize("options", [(), ("--table",)], ids=["", "table"])
def test_scan_line_finds_the_units_between_a_clients_requests(start_daemon, poll, options):
    gw, record = start_daemon(*options)
    poller = poll(gw)
    began = time.monotonic()
    done = mbgw("scan", "--line", "serial", "--units", "1-5", "--json", "--control",
                gw.control, timeout=60)
    ended = time.monotonic()
    answered_during_scan = poller.answers
    poller.finish()
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout)
    assert [(r["unit"], r["baudrate"], r["format"], r["exception"], r["identity"])
            for r in found] == [(2, 19200, "8n1", None, IDENTITY), (3, 19200, "8n1", None,
                                                                  IDENTITY)]
    assert all(0 <= r["p50_ms"] <= r["p99_ms"] < 1000 for r in found)
    assert poller.wrong == [] and answered_during_scan > 0, (began, ended, status(gw))
    # on the wire: the survey's reads (units 1-5 asked register 0 once each; the units
    # found timed and asked their identity) take turns with the client's: while a silent
    # unit's read waits out its 100 ms, the client's next request comes, and goes first
    rows = heard(record)
    survey = [i for i, row in enumerate(rows) if row[2] != CLIENT_PDU]
    assert list(dict.fromkeys(rows[i][0] for i in survey)) == [1, 2, 3, 4, 5]
    assert [rows[i][2] for i in survey if rows[i][0] == 2] == [REGISTER_0] * 6 + [IDENTIFY]
    silent = [i for i in survey if rows[i][0] in (1, 4, 5)]
    assert len(silent) == 3
    assert all(rows[i + 1][2] == CLIENT_PDU for i in silent if i + 1 < len(rows)), rows


def test_scan_line_text_is_the_device_forms(daemon):
    gw, _ = daemon
    done = mbgw("scan", "--line", "serial", "--units", "2", "--baudrates", BAUD,
                "--formats", "8n1", "--control", gw.control, timeout=30)
    assert done.returncode == 0, done.stderr
    assert re.fullmatch(r"unit 2: 19200 8n1, p50 \d+\.\d ms, p99 \d+\.\d ms, vendor 'mbgw "
                        r"test vendor', product_code 'PEER-17', revision '3\.16\.1'\n",
                        done.stdout), done.stdout


def test_probe_line_measures_each_unit_through_the_daemon(daemon):
    gw, _ = daemon
    done = mbgw("probe", "--line", "serial", "--units", "3,7", "--count", "5", "--timeout",
                "100", "--control", gw.control, timeout=30)
    assert done.returncode == 0, done.stderr
    first, second = done.stdout.splitlines()
    match = re.fullmatch(r"unit 3: 5 reads, 5 answered, p50 (\S+) ms, p99 (\S+) ms, "
                         r"recommended stout (\d+) ms", first)
    assert match, first
    assert second == "unit 7: 5 reads, 0 answered"


def test_probe_line_of_silent_units_exits_1(daemon):
    gw, _ = daemon
    done = mbgw("probe", "--line", "serial", "--units", "9", "--count", "2", "--timeout",
                "50", "--json", "--control", gw.control)
    assert done.returncode == 1
    assert json.loads(done.stdout)[0]["answered"] == 0
    assert done.stderr == "mbgw: no address answered on line serial\n"


@pytest.mark.parametrize("args, named", [
    (("scan", "--baudrates", "9600"), "--baudrates"),
    (("scan", "--baudrates", "19200,38400"), "--baudrates"),
    (("scan", "--formats", "8o1"), "--formats"),
    (("probe", "--units", "2", "--baudrate", "9600"), "--baudrate"),
    (("probe", "--units", "2", "--format", "8e1"), "--format"),
])
def test_settings_other_than_the_lines_are_a_usage_error(daemon, args, named):
    gw, record = daemon
    command, *options = args
    done = mbgw(command, "--line", "serial", *options, "--control", gw.control)
    assert done.returncode == 2, done.stderr
    assert f"'{named}'" in done.stderr and "running line's" in done.stderr
    assert heard(record) == []


def test_device_and_line_together_or_neither_is_a_usage_error(daemon, pty_pair):
    gw, _ = daemon
    for args in (("scan", pty_pair.gateway, "--line", "serial"), ("scan",),
                 ("probe", "--units", "2")):
        done = mbgw(*args, "--control", gw.control)
        assert done.returncode == 2, done.stderr
        assert "DEVICE or --line" in done.stderr


def test_an_unknown_line_exits_1_naming_it(daemon):
    gw, _ = daemon
    for command in (["scan", "--units", "1"], ["probe", "--units", "1"]):
        done = mbgw(*command, "--line", "meters", "--control", gw.control)
        assert done.returncode == 1
        assert done.stderr == "mbgw: no line 'meters' (lines: serial)\n"


def test_a_line_in_master_mode_exits_1_naming_it(pty_pair, start_gateway):
    gw = start_gateway(pty_pair.gateway, "--baudrate", BAUD, mode="master", listen=False)
    done = mbgw("scan", "--line", "serial", "--units", "1", "--control", gw.control)
    assert done.returncode == 1
    assert done.stderr.startswith("mbgw: line serial is in master mode: only a line in slave "
                                  "mode"), done.stderr


def test_probe_line_asks_a_line_in_slave_mode_of_a_master_mode_daemon(
        tmp_path, pty_pair, start_gateway, meters):  # noqa: F811
    config = lines_file(tmp_path / "lines.toml", [meters_line(meters)], [])
    gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", BAUD,
                       mode="master", listen=False)
    done = mbgw("probe", "--line", "meters", "--units", str(METER), "--count", "3",
                "--control", gw.control, timeout=30)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"unit {METER}: 3 reads, 3 answered, p50 "), done.stdout
    assert received(meters.record) == [bytes((METER,)) + bytes.fromhex("0300000001")] * 3
    done = mbgw("probe", "--line", "serial", "--units", "1", "--control", gw.control)
    assert done.returncode == 1
    assert "line serial is in master mode" in done.stderr


class SlowPoller(Poller):
    """Poller of the settings bus's slow unit: register 5, which holds 1005."""

    def run(self) -> None:
        while not self.stopping.is_set():
            try:
                got = self.client.read_holding_registers(5, count=1, device_id=4)
            except ModbusException as err:
                self.wrong.append(err)
                continue
            if got.isError() or got.registers != [1005]:
                self.wrong.append(got)
            else:
                self.answers += 1


@pytest.mark.serial          # the slave's 150 ms against the survey's 50 ms
def test_a_late_reply_to_a_survey_read_never_answers_a_client(tmp_path, start_peer,
                                                             start_gateway, poll):
    """Unit 4 answers after 150 ms; probed with a 50 ms timeout, each read gives up before
    the reply (register 0: 1000) comes.  Taken for the client's next request to unit 4, a
    read of one register too, it would give the client 1000 for register 5; the line sits
    the late reply out instead."""
    link = str(tmp_path / "ttyBUS")
    start_peer("settings_bus.py", link, "--unit", "4,19200,8n1,150,none")
    gw = start_gateway(link, "--baudrate", BAUD, "--stout", "1000")
    poller = SlowPoller(gw.port)
    poller.start()
    try:
        until(lambda: poller.answers, "the client answered", 10)
        done = mbgw("probe", "--line", "serial", "--units", "4", "--count", "4", "--timeout",
                    "50", "--control", gw.control, timeout=60)
        answered = poller.answers
    finally:
        poller.finish()
    assert done.returncode == 1, done.stderr
    assert done.stdout == "unit 4: 4 reads, 0 answered\n"
    assert poller.wrong == [] and answered > 1
