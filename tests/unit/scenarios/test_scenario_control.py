"""The operator's side of the scenarios with a real Table, real engines and a real control
socket (mbgw.ops.control.ControlServer in a thread): `mbgw scenarios`, `mbgw scenario
enable|disable [--save]`, `mbgw scenario test` run by a runner thread reading the engine's
wake_fd, the status section and the /metrics families."""
import asyncio
import json
import select
import threading
import time

import pytest
from click.testing import CliRunner
from prometheus_client import CollectorRegistry, generate_latest

from mbgw.cli import main
from mbgw.cli.render_scenarios import format_scenarios
from mbgw.config.scenario import parse_scenario
from mbgw.ops.control import ControlServer
from mbgw.ops.metrics_scenarios import scenario_families
from mbgw.scenarios.control import scenario_commands
from mbgw.scenarios.engine import Scenarios
from mbgw.scenarios.report import scenarios_status
from mbgw.table.memory import Table

H = bytes.fromhex
FILE = """[serial]
device = "/dev/null"

[[scenario]]
name = "boiler"
slave = 45
function = 3
address = 1000
quantity = 2
table = 0
cycle = 3000

[[scenario]]
name = "remote"
server = "192.0.2.1"
function = 16
address = 0
quantity = 1
table = 9
trigger = "change"
enabled = false
"""


def scenarios_of(text):
    import tomllib
    return [parse_scenario(f, "s") for f in tomllib.loads(text)["scenario"]]


class Runner(threading.Thread):
    """A stand-in for a runner's loop: sleeps in poll on wake_fd, runs the tests it is
    given with a scripted device (`reply(pdu)` -> (reply, error, retries))."""

    def __init__(self, engine, reply):
        super().__init__(daemon=True)
        self.engine, self.reply, self.stop = engine, reply, False
        self.seen = []

    def run(self):
        while not self.stop:
            select.select([self.engine.wake_fd], [], [], 0.2)
            self.engine.due_in(time.monotonic())
            test = self.engine.take_test(time.monotonic())
            if test is not None:
                self.seen.append(test.pdu)
                self.engine.test_done(test, *self.reply(test.pdu))


@pytest.fixture
def daemon(tmp_path):
    conf = tmp_path / "mbgw.toml"
    conf.write_text(FILE)
    table = Table()
    configs = scenarios_of(FILE)
    engines = {"serial": Scenarios(configs, table, "serial"),
               "tcp": Scenarios(configs, table, "tcp")}
    path = str(tmp_path / "mbgw.sock")
    loop = asyncio.new_event_loop()
    server = ControlServer(path, scenario_commands(engines, conf))
    loop.run_until_complete(server.start())
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    runner = Runner(engines["serial"], lambda pdu: (H("03 04 00 0b 00 0c"), None, 1))
    runner.start()
    yield {"conf": conf, "table": table, "engines": engines, "path": path, "runner": runner}
    runner.stop = True
    runner.join(5)
    loop.call_soon_threadsafe(loop.stop)
    thread.join(10)
    server.close()
    loop.close()


def mbgw(daemon, *args):
    return CliRunner().invoke(main, [*args, "--control", daemon["path"]])


def test_scenarios_lists_them(daemon):
    result = mbgw(daemon, "scenarios")
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == "scenarios (2)"
    assert lines[2].split()[:5] == ["boiler", "starting", "slave", "45", "3"]
    assert lines[3].split()[:2] == ["remote", "disabled"]
    rows = json.loads(mbgw(daemon, "scenarios", "--json").output)
    assert [(r["name"], r["kind"], r["state"]) for r in rows] == \
        [("boiler", "serial", "starting"), ("remote", "tcp", "disabled")]


def test_enable_disable_until_reload(daemon):
    result = mbgw(daemon, "scenario", "disable", "boiler")
    assert result.exit_code == 0, result.output
    assert result.output == "scenario boiler disabled until the next reload\n"
    assert daemon["engines"]["serial"].status()[0]["state"] == "disabled"
    assert daemon["conf"].read_text() == FILE
    result = mbgw(daemon, "scenario", "enable", "nope")
    assert result.exit_code == 1
    assert "no scenario 'nope' (scenarios: boiler, remote)" in result.output


def test_enable_disable_saved(daemon):
    assert mbgw(daemon, "scenario", "enable", "remote", "--save").exit_code == 0
    assert daemon["engines"]["tcp"].status()[0]["state"] == "starting"
    assert "enabled = false" not in daemon["conf"].read_text()
    result = mbgw(daemon, "scenario", "disable", "boiler", "--save")
    assert result.output == "scenario boiler disabled, saved in the configuration file\n"
    assert [sc.enabled for sc in scenarios_of(daemon["conf"].read_text())] == [False, True]


def test_scenario_test_runs_on_the_runner(daemon):
    result = mbgw(daemon, "scenario", "test", "slave=45", "function=3", "address=1000",
                  "quantity=2", "table=0")
    assert result.exit_code == 0, result.output
    assert daemon["runner"].seen == [H("03 03 e8 00 02")]
    lines = result.output.splitlines()
    assert lines[0].startswith("ok: ok (") and lines[0].endswith(", 1 retries)")
    assert lines[1:] == ["request  03 03 e8 00 02", "reply    03 04 00 0b 00 0c",
                         "data     (2 from 1000)", "     11    12"]
    assert daemon["table"].read(0, 2) == [0, 0]          # a test stores nothing


def test_scenario_test_errors(daemon):
    daemon["runner"].reply = lambda pdu: (None, "timeout", 2)
    result = mbgw(daemon, "scenario", "test", "slave=45", "function=3", "address=1000",
                  "quantity=2", "table=0")
    assert result.exit_code == 1
    assert result.output.startswith("error: timeout, no answer from slave after retrying")
    result = mbgw(daemon, "scenario", "test", "slave=45", "function=3", "address=1000",
                  "quantity=200", "table=0")
    assert result.exit_code == 1
    assert "scenario test: quantity 200: out of range 1..125" in result.output
    result = mbgw(daemon, "scenario", "test", "slave=45", "function")
    assert result.exit_code == 2 and "'function': expected KEY=VALUE" in result.output


def test_status_section_and_metrics():
    table = Table()
    engine = Scenarios(scenarios_of(FILE), table, "serial", clock=lambda: 10.0)
    run = engine.next(10.0)
    engine.done(run, None, "timeout", retries=2)
    rows = scenarios_status([engine, None])
    lines = format_scenarios(rows, time.time())
    assert lines[2].split()[:2] == ["boiler", "error"]
    assert lines[3] == "    error: timeout, no answer from slave after retrying"

    class Collector:
        def collect(self):
            yield from scenario_families(rows)
    registry = CollectorRegistry()
    registry.register(Collector())
    text = generate_latest(registry).decode()
    for line in ['mbgw_scenario_runs_total{scenario="boiler"} 1.0',
                 'mbgw_scenario_errors_total{kind="timeout",scenario="boiler"} 1.0',
                 'mbgw_scenario_retries_total{scenario="boiler"} 2.0',
                 'mbgw_scenario_overruns_total{scenario="boiler"} 0.0',
                 'mbgw_scenario_state{scenario="boiler",state="error"} 1.0',
                 'mbgw_scenario_state{scenario="boiler",state="running"} 0.0']:
        assert line in text
    assert "mbgw_scenario_data_age_seconds{" not in text        # no data yet
