"""Demotion, refined (issue 29): the line thread probes an address that is down by itself, at
the probe interval, with the last read the device answered, waiting for the device's own
learnt response time (3 x its p99, at least 20 ms, at most stout) rather than a whole stout;
the first answer brings it back with no client asking.  An address is down only after
down-after failures in a row (and down-after x stout without an answer).

The fault slave (tests/peers/fault_slave.py) records each frame it receives with its arrival
time (time.monotonic(), the test's clock too): its address 18 answers its first 5 requests
after 10 ms, is silent to the next 3, then answers again; address 12 answers every second
request; address 2 never answers.  Timings are checked on that record: lower bounds the
gateway must respect, and one upper bound half a stout away from what the rule gives (a probe
waits ~35 ms, or ~20 ms on the line's learnt time; stout is 600 ms).  The test that only
counts outcomes runs with a stout of 200 ms, since each of its timeouts costs two stouts.
"""
import threading

import pytest

from tests.integration.slave.test_faults import received
from tests.modbus import Client, holding_reply, read_holding
from tests.ops import devices, health_log, mbgw, status, wait_for
from tests.wait import until

pytestmark = [pytest.mark.integration, pytest.mark.serial]

STOUT_MS = 600
STOUT_S = STOUT_MS / 1000
COUNTING_STOUT_MS = 200
PEER_CLOCK_S = 0.005          # how late the slave may date a frame
INTERVAL_MS = 300
INTERVAL_S = INTERVAL_MS / 1000
DOWN_AFTER = 2
STOPS = 18                    # fault_slave: 5 answers, 3 silences, then answers again
EVERY_OTHER = 12              # fault_slave: answers every second request
SILENT = 2                    # fault_slave: never answers
READ = read_holding(0, 1)
NO_ANSWER = b"\x83\x0b"
WRITE = bytes.fromhex("06 00 05 00 07")     # FC 6, echoed: answered, never a probe


@pytest.fixture
def gateway(pty_pair, recording_peer, start_gateway, shortcut_both_ways):
    """gateway(stout_ms=STOUT_MS) -> (a ready gateway, the fault slave's record)."""
    def start(stout_ms: int = STOUT_MS):
        record = recording_peer("fault_slave.py", "--reply-delay-ms", "10")
        gw = start_gateway(pty_pair.gateway, "--baudrate", "38400", "--stout", str(stout_ms),
                           "--down-after", str(DOWN_AFTER), "--probe-interval",
                           str(INTERVAL_MS), "--exception", *shortcut_both_ways)
        return gw, record
    return start


class Poller:
    """A client reading address 1 in a closed loop (its requests are what the line carries
    right after a probe), until stopped."""

    def __init__(self, gw) -> None:
        self.client = Client(gw.port)
        self.errors: list[BaseException] = []
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            while not self.stopping.is_set():
                assert self.client.ask(1, READ) == holding_reply(0, 1)
        except BaseException as error:      # reported by stop()
            self.errors.append(error)

    def stop(self) -> None:
        self.stopping.set()
        self.thread.join()
        self.client.close()
        assert not self.errors, self.errors


def frames_to(record, address: int) -> list[tuple[float, bytes]]:
    """(arrival, address + PDU) of each frame for address."""
    return [(when, frame[:-2]) for when, frame in received(record) if frame[0] == address]


def test_a_probe_is_the_last_answered_read_waits_the_learnt_time_and_needs_no_client(
        gateway, client):
    """4 reads and a write answered in ~10 ms, then 2 reads unanswered: down.  With no client
    asking, the line thread probes at the interval (then twice it) with the last read that
    was answered (not the write, not the read that failed); the first probe waits the
    learnt timeout only (the poller's next request follows it by less than half a stout);
    the second is answered and the address is back."""
    gw, record = gateway()
    c = client(gw)
    for start in range(4):
        assert c.ask(STOPS, read_holding(start, 1)) == holding_reply(start, 1)
    assert c.ask(STOPS, WRITE) == WRITE
    for _ in range(DOWN_AFTER):
        assert c.ask(STOPS, read_holding(7, 1)) == NO_ANSWER
    # the first probe waits for the late window of the last failure (late-window: stout)
    poller = Poller(gw)
    try:
        d = devices(wait_for(gw, lambda s: True, "status"))[STOPS]
        assert d["health"] == "down" and d["next_probe_in_s"] is not None, d
        wait_for(gw, lambda s: devices(s)[STOPS]["health"] != "down", "the address back")
    finally:
        poller.stop()
    p99_ms, timeout_ms = d["learnt_p99_ms"], d["probe_timeout_ms"]
    assert 10 <= p99_ms < STOUT_MS / 6, d
    assert timeout_ms == pytest.approx(max(3 * p99_ms, 20), abs=0.01), d
    assert d["stout_ms"] == STOUT_MS
    shown = mbgw("status", "--control", gw.control).stdout
    learnt = devices(status(gw))[STOPS]
    assert f"        learnt p99 {learnt['learnt_p99_ms']:.1f} ms, probe timeout " \
           f"{learnt['probe_timeout_ms']:.1f} ms" in shown, shown
    assert health_log(gw, STOPS)[-2:] == ["down", "degraded"]

    frames = frames_to(record, STOPS)
    assert len(frames) == 5 + DOWN_AFTER + 2, frames       # 2 probes, no client's request
    last_read = bytes((STOPS,)) + read_holding(3, 1)
    assert [f for _, f in frames[-2:]] == [last_read, last_read]
    failed_at, first, second = frames[-3][0], frames[-2][0], frames[-1][0]
    assert first - failed_at >= STOUT_S + INTERVAL_S       # the failure came stout after
    assert second - first >= 2 * INTERVAL_S                 # doubled after a failed probe
    after = [when for when, f in received(record) if f[0] == 1 and first < when < second]
    assert after, "the poller had no request on the line between the probes"
    gap = after[0] - first
    # the slave dates a frame as it wakes up for it: the probe's date may be a few ms late
    assert timeout_ms / 1000 - PEER_CLOCK_S <= gap < STOUT_S / 2, (gap, timeout_ms)


def test_a_device_answering_every_other_request_is_never_demoted(gateway, client):
    """Its failures never come down-after in a row: all its requests go on the line."""
    gw, record = gateway(COUNTING_STOUT_MS)
    c = client(gw)
    answers = [c.ask(EVERY_OTHER, READ) for _ in range(4 * DOWN_AFTER)]
    assert answers == [NO_ANSWER, holding_reply(0, 1)] * (2 * DOWN_AFTER)
    until(lambda: len(frames_to(record, EVERY_OTHER)) == 4 * DOWN_AFTER,
          "every request on the line", 5)
    d = devices(status(gw))[EVERY_OTHER]
    assert (d["health"], d["demoted_rejects"], d["timeouts"]) == ("degraded", 0, 2 * DOWN_AFTER)
    assert "is down" not in gw.log()


def test_a_unit_that_never_answered_is_probed_with_the_learnt_time_of_its_line(
        gateway, client):
    """Address 2 has never answered; address 1, beside it, answers the poller in a few ms.
    Once 2 is down, its probe (the first read that timed out) waits 3 x the p99 of the
    line's answers (at least 20 ms), not its stout: the poller's next request follows the
    probe by less than half a stout (and by a stout before issue 29's line-wide time)."""
    gw, record = gateway()
    c = client(gw)
    poller = Poller(gw)
    try:
        first_failed = read_holding(7, 1)
        assert c.ask(SILENT, first_failed) == NO_ANSWER
        assert c.ask(SILENT, read_holding(8, 1)) == NO_ANSWER
        until(lambda: len(frames_to(record, SILENT)) >= DOWN_AFTER + 1, "a probe of unit 2",
              10 * STOUT_S)
        d = devices(status(gw))[SILENT]
        until(lambda: [w for w, _ in frames_to(record, 1)
                       if w > frames_to(record, SILENT)[DOWN_AFTER][0]],
              "a request of the poller after the probe", 5)
    finally:
        poller.stop()
    assert (d["health"], d["learnt_p99_ms"], d["replies"]) == ("down", None, 0), d
    timeout_ms = d["probe_timeout_ms"]
    # the line's answers are all address 1's: its learnt p99 is the line's (read once the
    # poller has stopped, so that both come from the same answers)
    s = devices(status(gw))
    line_p99 = s[1]["learnt_p99_ms"]
    assert s[SILENT]["probe_timeout_ms"] == pytest.approx(max(3 * line_p99, 20), abs=0.01), s
    assert 20 <= timeout_ms < STOUT_MS, d

    frames = frames_to(record, SILENT)
    probe = bytes((SILENT,)) + first_failed
    assert [f for _, f in frames[DOWN_AFTER:]] == [probe] * (len(frames) - DOWN_AFTER), frames
    probed = frames[DOWN_AFTER][0]
    after = [when for when, f in received(record) if f[0] == 1 and when > probed]
    gap = after[0] - probed     # the line's p99 moves with the poller's: 20 ms, the least
    assert 0.02 <= gap < STOUT_S / 2, (gap, timeout_ms)
