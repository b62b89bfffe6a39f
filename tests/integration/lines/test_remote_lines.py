"""Lines beyond the local serial port (issue 26): a `[[line]]` whose device is across the
network (`connect`), reached from the Modbus TCP face like any other line.

Peers that are not ours: a device emulator that takes one TCP connection and resets any
other (tests/peers/single_client_device.py, Modbus TCP or RTU frames, its replies late,
twice, cut in 1-byte segments or joined), a pymodbus RTU slave behind socat's TCP listener,
pymodbus's Modbus/UDP server, raw sockets and pymodbus/mbpoll clients in front.
"""
import json
import struct
import threading

import pytest

from tests.integration.lines.test_lines import Line, lines  # noqa: F401 (a fixture)
from tests.modbus import Client, read_holding
from tests.ops import status, wait_for, wait_for_log
from tests.peers.single_client_device import LATE_REGISTER, TWICE_REGISTER, SingleClientDevice

pytestmark = pytest.mark.integration

INVERTER = 40             # the TCP face's units 40-49 go to line inverter, unchanged
STOUT_MS = 300


def reply(start: int, count: int) -> bytes:
    """The emulator's: holding register n holds 100 + n."""
    return bytes((0x03, 2 * count)) + b"".join(struct.pack(">H", 100 + start + i)
                                                for i in range(count))


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
def gateway(tmp_path, lines, start_gateway):  # noqa: F811 (this module's own)
    """gateway(url, *options, **line) -> mbgw slave with line serial on a pty (a pymodbus
    slave at 5) and line inverter at url, its [[line]] keys `line`."""
    def start(url: str, *options: str, **line):
        serial = lines("serial", 5)
        path = tmp_path / "mbgw.toml"
        path.write_text(remote_toml(url, **line))
        return start_gateway(serial.pair.gateway, "--config", str(path), "--baudrate", "19200",
                             "--stout", "300", "--exception", *options)
    return start


def test_a_modbus_tcp_device_answers_through_its_line(gateway, client, device):
    d = device(delays=(0.005, 0.02))
    gw = gateway(d.url)
    c = client(gw)
    assert c.ask(INVERTER, read_holding(3, 4)) == reply(3, 4)
    assert c.ask(INVERTER + 1, read_holding(0, 1)) == reply(0, 1)
    assert d.requests == [(INVERTER, read_holding(3, 4)), (INVERTER + 1, read_holding(0, 1))]
    s = status(gw)
    row = next(r for r in s["lines"] if r["name"] == "inverter")
    assert (row["state"], row["device"]) == ("up", d.url)
    assert (d.connections, d.resets) == (1, 0)
