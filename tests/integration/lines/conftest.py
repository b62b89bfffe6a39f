"""A daemon with a remote line (issue 26), for the tests of remote lines and lent clients:
line serial on a pty (a pymodbus slave at 5, units 1-31) and line inverter at a URL (units
40-49, unchanged), and the single-connection device emulator behind it."""
import json

import pytest

from tests.integration.lines.test_lines import lines  # noqa: F401 (a fixture)
from tests.peers.single_client_device import SingleClientDevice

INVERTER = 40             # the TCP face's units 40-49 go to line inverter, unchanged
STOUT_MS = 300


@pytest.fixture
def device():
    """device(**options) -> a SingleClientDevice; stopped after the test."""
    started: list[SingleClientDevice] = []

    def start(**options) -> SingleClientDevice:
        started.append(SingleClientDevice(**options))
        return started[-1]
    yield start
    for d in started:
        d.stop()


def remote_toml(url: str, **line) -> str:
    """Line inverter at url (units 40-49, unchanged), line serial units 1-31."""
    fields = {"name": "inverter", "connect": url, "stout": STOUT_MS, **line}
    return "\n".join(["[[line]]", *(f"{k} = {json.dumps(v)}" for k, v in fields.items()),
                      "[[route]]", 'units = "1-31"', 'line = "serial"',
                      "[[route]]", 'units = "40-49"', 'line = "inverter"', ""])


@pytest.fixture
def remote_gateway(tmp_path, lines, start_gateway):  # noqa: F811 (the fixture imported)
    """remote_gateway(url, *options, rules="", **line) -> mbgw slave with line serial and
    line inverter at url, its [[line]] keys `line`; rules: more of the file (firewall
    rules)."""
    def start(url: str, *options: str, rules: str = "", **line):
        serial = lines("serial", 5)
        path = tmp_path / "mbgw.toml"
        path.write_text(remote_toml(url, **line) + rules)
        return start_gateway(serial.pair.gateway, "--config", str(path), "--baudrate", "19200",
                             "--stout", str(STOUT_MS), "--exception", *options)
    return start
