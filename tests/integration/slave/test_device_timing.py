"""Per-device timing (issue 29): `[[device]]` tables give a unit its own stout, retries and
pause on its line, over the line's.

The scripted slave of tests/peers/fault_slave.py records each frame it receives and sends
with time.monotonic() (the test's clock too): what went on the line, and when, is read from
that record.  Its address 2 never answers, 3 answers after --late-ms, 1 and 6 at once.  Each
test runs with the idle line's shortcut (C puts a request that finds the line idle on it)
and without: C knows only the line's stout, so it must hand a unit with its own timing back.
"""
import os
import signal
import time

import pytest

from tests.integration.slave.test_faults import received
from tests.modbus import holding_reply, mbap, read_holding
from tests.ops import devices, mbgw, status, wait_for_log

pytestmark = pytest.mark.integration

READ = read_holding(0, 1)
REPLY = holding_reply(0, 1)
NO_ANSWER = b"\x83\x0b"
SILENT, SLOW, PROMPT, PLAIN = 2, 3, 1, 6     # fault_slave's addresses
LINE_STOUT_MS = 300         # told apart from every [[device]] stout here (50, 400, 900)


@pytest.fixture
def gateway(pty_pair, recording_peer, start_gateway, shortcut_both_ways, tmp_path):
    """gateway(devices_toml, *options) -> (a ready gateway with --exception, the line's stout
    LINE_STOUT_MS and the [[device]] tables given in its file; the slave's record)."""
    def start(devices_toml: str, *options: str):
        record = recording_peer("fault_slave.py", "--late-ms", "700")
        config = tmp_path / "mbgw.toml"
        config.write_text(f"[serial]\nstout = {LINE_STOUT_MS}\n" + devices_toml)
        gw = start_gateway(pty_pair.gateway, "--config", str(config), "--baudrate", "38400",
                           "--exception", *shortcut_both_ways, *options)
        return gw, record, config
    return start


# how late the slave may date a frame (it dates one when it wakes for it): a gap it measures
# between two frames may fall short of the gateway's by that much
PEER_CLOCK_S = 0.005


def ask(c, tid: int, unit: int) -> bytes:
    c.send(mbap(tid, unit, READ))
    got = c.recv()
    assert got is not None and got[:2] == (tid, unit), got
    return got[2]


def sent_to(record, unit: int) -> list[float]:
    return [when for when, frame in received(record) if frame[0] == unit]


def replies(record) -> list[tuple[float, bytes]]:
    """(time, frame) for every reply the slave wrote."""
    rows = (line.split(" ", 2) for line in record.read_text().splitlines())
    return [(float(when), bytes.fromhex(data)) for when, kind, data in rows if kind == "tx"]


@pytest.mark.serial
def test_a_fast_devices_timeout_is_told_at_its_own_stout_while_the_slow_one_works(
        gateway, client):
    """Line stout 300 ms; a [[device]] stout of 50 ms for the device that stopped
    answering: the next request goes on the line 50 to 100 ms after its request; the 700 ms
    device, with stout 900, answers; status shows each one's timing."""
    gw, record, _ = gateway(f"[[device]]\nunit = {SILENT}\nstout = 50\n"
                            f"[[device]]\nunit = {SLOW}\nstout = 900\n")
    c = client(gw)
    assert ask(c, 1, PROMPT) == REPLY
    # Not a wait for an event: the line must have been silent for t3.5 past that reply for
    # the next request to find it idle, the shortcut's case (the C shortcut knows only the
    # line's stout: it would wait 300 ms)
    time.sleep(0.02)
    assert ask(c, 2, SILENT) == NO_ANSWER
    assert ask(c, 3, PROMPT) == REPLY
    (silent,), prompt = sent_to(record, SILENT), sent_to(record, PROMPT)[-1]
    assert 0.045 <= prompt - silent < 0.100     # the peer's clock: a few ms of slack
    assert ask(c, 4, SLOW) == REPLY
    shown = devices(status(gw))
    assert shown[SILENT]["timing"]["stout_ms"] == 50
    assert shown[SLOW]["timing"] == {"stout_ms": 900, "retries": 0, "pause_ms": 0,
                                     "down_after": 3, "probe_interval_ms": 5000}
    assert "timing" not in shown[PROMPT]
    assert "own timing: stout 900 ms, retries 0, pause 0 ms" in \
        mbgw("status", "--control", gw.control).stdout


@pytest.mark.serial
def test_a_devices_pause_is_the_silence_before_each_of_its_frames_retries_included(
        gateway, client):
    """pause = 150 for the silent device, with 3 retries of its own (the line has 1) and a
    stout of 50: 4 frames to it, each at least 150 ms after the line last carried a byte;
    a device without its own pause goes right after the reply before it; the line's retries
    for the others (2 frames to an address that does not answer)."""
    gw, record, _ = gateway(f"[[device]]\nunit = {SILENT}\nstout = 50\nretries = 3\n"
                            f"pause = 150\n"
                            f"[[device]]\nunit = {PLAIN}\npause = 150\n", "--retries", "1")
    c = client(gw)
    assert ask(c, 1, PROMPT) == REPLY
    assert ask(c, 2, PLAIN) == REPLY
    assert ask(c, 3, SILENT) == NO_ANSWER
    assert ask(c, 4, 15) == NO_ANSWER       # fault_slave's 15: garbage, never the reply
    tries = sent_to(record, SILENT)
    assert len(tries) == 4 and len(sent_to(record, 15)) == 2
    reply_before_plain = max(t for t, frame in replies(record) if frame[0] == PROMPT)
    (plain,) = sent_to(record, PLAIN)
    assert plain - reply_before_plain >= 0.150 - PEER_CLOCK_S
    reply_before_silent = max(t for t, frame in replies(record) if frame[0] == PLAIN)
    gaps = [b - a for a, b in zip([reply_before_silent, *tries[:-1]], tries, strict=True)]
    assert all(gap >= 0.140 for gap in gaps), gaps     # without the pause: 50 ms apart
    counted = devices(status(gw))
    assert counted[SILENT]["retries"] == 3 and counted[15]["retries"] == 1


def test_a_reload_gives_a_device_its_new_stout_between_transactions(gateway, client):
    """The silent device's stout 50 becomes 400 with a reload: its next timeout is told
    only after 400 ms on the line."""
    gw, record, config = gateway(f"[[device]]\nunit = {SILENT}\nstout = 50\n")
    c = client(gw)
    assert ask(c, 1, SILENT) == NO_ANSWER
    config.write_text(f"[serial]\nstout = {LINE_STOUT_MS}\n"
                      f"[[device]]\nunit = {SILENT}\nstout = 400\n")
    os.kill(gw.proc.pid, signal.SIGHUP)
    wait_for_log(gw, "configuration reloaded: devices changed")
    assert ask(c, 2, SILENT) == NO_ANSWER
    assert ask(c, 3, PROMPT) == REPLY
    silent, prompt = sent_to(record, SILENT)[-1], sent_to(record, PROMPT)[-1]
    assert prompt - silent >= 0.400 - PEER_CLOCK_S
    assert devices(status(gw))[SILENT]["timing"]["stout_ms"] == 400
