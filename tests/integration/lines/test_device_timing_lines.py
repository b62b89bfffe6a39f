"""[[device]] on a line beside serial (issue 29): a unit of line meters has its own stout,
over the line's, at start and after a reload that changes only the [[device]] table.

Peers: pymodbus RTU slaves on socat pty pairs, each recording what its line carried and
when (time.monotonic(), the test's clock too); an address the slave lacks stays silent."""
import os
import signal

import pytest

from tests.integration.lines.test_lines import Line, gateway, hr_reply, lines, write_lines
from tests.modbus import Client, mbap, read_holding
from tests.ops import status, wait_for_log

__all__ = ["gateway", "lines"]      # the fixtures, shared

pytestmark = pytest.mark.integration

METER, MUTE = 1, 2          # on line meters: the slave has address 1 only
LINE_STOUT_MS = 1000
NO_ANSWER = b"\x83\x0b"


def spec(meters: Line) -> dict:
    return {"lines": [{"name": "meters", "device": meters.pair.gateway,
                       "stout": LINE_STOUT_MS}],
            "routes": [{"units": "1-31", "line": "serial"},
                       {"units": "32-63", "line": "meters", "offset": -31}]}


def with_device(directory, meters: Line, stout_ms: int) -> None:
    write_lines(directory, spec(meters))
    with open(directory / "mbgw.toml", "a") as f:
        f.write(f'[[device]]\nline = "meters"\nunit = {MUTE}\nstout = {stout_ms}\n')


def sent(meters: Line, address: int) -> list[float]:
    rows = (row.split() for row in meters.record.read_text().splitlines())
    return [float(when) for when, kind, frame in rows
            if kind == "rx" and bytes.fromhex(frame)[0] == address]


def ask(c: Client, tid: int, unit: int) -> bytes:
    c.send(mbap(tid, unit, read_holding(0, 1)))
    got = c.recv()
    assert got is not None and got[:2] == (tid, unit), got
    return got[2]


@pytest.mark.serial
def test_a_unit_of_another_line_has_its_own_stout_and_a_reload_changes_it(
        tmp_path, lines, gateway):
    serial, meters = lines("serial", 5), lines("meters", METER)
    (tmp_path / "mbgw.toml").write_text("[net]\nexception = true\n")
    gw = gateway(serial, spec(meters))    # no [[device]] yet: a reload adds it
    with_device(tmp_path, meters, 40)
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: devices changed")
    c = Client(gw.port)
    try:
        assert ask(c, 1, 31 + MUTE) == NO_ANSWER
        assert ask(c, 2, 31 + METER) == hr_reply(0, 1)
        assert sent(meters, METER)[-1] - sent(meters, MUTE)[-1] < LINE_STOUT_MS / 2000
        meters_row = next(r for r in status(gw)["lines"] if r["name"] == "meters")
        mute = next(d for d in meters_row["devices"] if d["address"] == MUTE)
        assert mute["timing"]["stout_ms"] == 40
        with_device(tmp_path, meters, 700)
        os.kill(gw.proc.pid, signal.SIGHUP)
        wait_for_log(gw, "configuration reloaded: devices changed", 2)
        assert ask(c, 3, 31 + MUTE) == NO_ANSWER
        assert ask(c, 4, 31 + METER) == hr_reply(0, 1)
        assert sent(meters, METER)[-1] - sent(meters, MUTE)[-1] >= 0.7
    finally:
        c.close()
