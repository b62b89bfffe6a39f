"""Slave mode against a scripted serial slave that misbehaves on purpose (peers/fault_slave.py).

The clients here are raw sockets with hand-built MBAP frames, so every assertion is on the
exact bytes.  Where a test needs "no reply", it pipelines a request to the well-behaved unit 1
behind the faulty one whenever it can: the line serves a client's requests in order, so the
first reply to arrive must be unit 1's.  Each test ends by stopping the gateway and checking
the counters it logs at stop.
"""
import functools
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.harness import READY_TIMEOUT_S, free_port, stop, stop_counters
from tests.modbus import holding_reply, mbap, read_holding, rtu
from tests.ops import tracing, wait_for
from tests.peers import fault_slave
from tests.wait import until

pytestmark = pytest.mark.integration

STOUT_MS = 200
STOUT_S = STOUT_MS / 1000
NO_REPLY_S = STOUT_S + 0.15         # long enough for a reply that would come at stout
VENDOR_FC = fault_slave.VENDOR_FC   # ICP DAS FC 108, sub-function 07: read range code
VENDOR_REQUEST = bytes((VENDOR_FC, 0x07, 0x01, 0x00))

# Counters every test checks; any not named in the expectation must stay at 0.
CHECKED = ("requests", "replies", "device_exceptions", "gateway_exceptions", "timeouts",
           "retries", "crc_errors", "invalid_frames", "wrong_unit", "wrong_function",
           "late_replies", "late_bytes", "broadcasts", "unroutable", "line_down_rejects",
           "noise_bytes")


@pytest.fixture
def line(recording_peer):
    """line(*peer_options) -> the path of the peer's record; the peer is ready."""
    return functools.partial(recording_peer, "fault_slave.py")


@pytest.fixture
def gateway(pty_pair, start_gateway, shortcut_both_ways):
    """gateway(*options) -> a ready gateway on the pty pair with stout STOUT_MS, at 38400
    bit/s unless told (t3.5 = 1.75 ms, well under the peer's pauses).  Every test runs twice:
    with the idle line's shortcut (a request that finds the line idle goes on it from C,
    csrc/forward.c) and without it (every request through the queue, SerialMaster.transact)."""
    def start(*options: str, baudrate: int = 38400):
        return start_gateway(pty_pair.gateway, "--baudrate", str(baudrate),
                             "--stout", str(STOUT_MS), *shortcut_both_ways, *options)
    return start


def received(record) -> list[tuple[float, bytes]]:
    """(arrival time, frame) for every frame the slave received, in order."""
    frames = []
    for line in record.read_text().splitlines():
        when, kind, data = line.split(" ", 2)
        if kind.startswith("rx"):
            assert kind == "rx", f"the slave got a broken frame: {line}"
            frames.append((float(when), bytes.fromhex(data)))
    return frames


def assert_counters(gw, **expected: int) -> dict[str, int]:
    counters = stop_counters(gw)
    want = {name: expected.pop(name, 0) for name in CHECKED}
    got = {name: counters[name] for name in CHECKED}
    for name, value in expected.items():     # unchecked ones named explicitly
        want[name], got[name] = value, counters[name]
    assert got == want
    return counters


# --- well-behaved slave ---------------------------------------------------------------------

def test_normal_reply_is_byte_exact_with_the_clients_tid_and_unit(line, gateway, client):
    record = line()
    gw = gateway()
    c = client(gw)
    c.send(mbap(0xBEEF, 1, read_holding(0x10, 5)))
    reply = c.recv_raw()
    assert reply == (b"\xbe\xef\x00\x00\x00\x0d\x01\x03\x0a"
                     b"\x03\xf8\x03\xf9\x03\xfa\x03\xfb\x03\xfc")
    assert [f for _, f in received(record)] == [bytes.fromhex("01 03 00 10 00 05 84 0c")]
    assert_counters(gw, requests=1, replies=1)


def test_peer_crc_matches_the_published_vector():
    assert fault_slave.crc16(bytes.fromhex("11 03 00 6b 00 03")) == b"\x76\x87"
    assert rtu(1, read_holding(0x10, 5)) == bytes.fromhex("01 03 00 10 00 05 84 0c")


# --- no reply at all ------------------------------------------------------------------------

def test_silent_slave_gets_no_reply_and_the_connection_keeps_working(line, gateway, client):
    record = line()
    gw = gateway()
    c = client(gw)
    c.send(mbap(1, 2, read_holding(0, 1)))
    assert c.recv(NO_REPLY_S) is None
    c.send(mbap(2, 1, read_holding(0, 1)))
    assert c.recv() == (2, 1, holding_reply(0, 1))
    assert [f[0] for _, f in received(record)] == [2, 1]
    assert_counters(gw, requests=2, replies=1, timeouts=1)


def test_silent_slave_with_exception_gets_0x0b_after_stout(line, gateway, client):
    line()
    gw = gateway("--exception")
    c = client(gw)
    sent = time.monotonic()
    c.send(mbap(7, 2, read_holding(0, 1)))
    assert c.recv() == (7, 2, b"\x83\x0b")
    assert time.monotonic() - sent >= STOUT_S
    c.send(mbap(8, 1, read_holding(0, 1)))
    assert c.recv() == (8, 1, holding_reply(0, 1))
    assert_counters(gw, requests=2, replies=2, timeouts=1, gateway_exceptions=1)


# --- late replies ---------------------------------------------------------------------------

@pytest.mark.serial
@pytest.mark.parametrize("exception", [False, True])
def test_late_reply_is_never_taken_for_the_next_requests_answer(line, gateway, client,
                                                                 exception):
    """A (unit 3, 3 registers at 0) times out; B (unit 3, 5 registers at 10) waits for unit 3's
    late window: A's late reply (300 ms > stout 200 ms) comes into the idle line, is dropped
    and counted, then B goes out.  B's own late reply comes after C's answer, into an idle
    line: counted too, and never forwarded."""
    record = line("--late-ms", "300")
    gw = gateway(*(["--exception"] if exception else []))
    c = client(gw)
    c.send(mbap(1, 3, read_holding(0, 3)), mbap(2, 3, read_holding(10, 5)),
           mbap(3, 1, read_holding(0, 2)))
    if exception:
        assert c.recv() == (1, 3, b"\x83\x0b")
        assert c.recv() == (2, 3, b"\x83\x0b")
    assert c.recv() == (3, 1, holding_reply(0, 2))
    # B's own late reply comes ~100 ms after C's answer, into an idle line: still nothing
    assert c.recv(0.3) is None
    frames = received(record)
    assert [f for _, f in frames] == [rtu(3, read_holding(0, 3)), rtu(3, read_holding(10, 5)),
                                      rtu(1, read_holding(0, 2))]
    # A's late reply came before B went out (the peer logged when it sent it)
    sent = sent_by_peer(record, rtu(3, holding_reply(0, 3)))
    assert len(sent) == 1 and frames[0][0] < sent[0] < frames[1][0]
    wait_for(gw, lambda s: s["counters"]["late_replies"] == 2, "B's late reply counted")
    assert_counters(gw, requests=3, replies=3 if exception else 1, timeouts=2,
                    gateway_exceptions=2 if exception else 0, late_replies=2,
                    unsolicited_frames=0, unsolicited_bytes=0)


@pytest.mark.serial
def test_late_reply_during_the_turnaround_counts_as_late_bytes(line, gateway, client):
    """A (unit 3) times out, a broadcast goes out, and A's late reply arrives during the
    turnaround that holds the next request back: it is discarded as late bytes."""
    record = line("--late-ms", "300")
    gw = gateway("--turnaround", "300")
    c = client(gw)
    c.send(mbap(1, 3, read_holding(0, 3)), mbap(2, 0, b"\x06\x00\x01\x00\x2a"),
           mbap(3, 1, read_holding(0, 1)))
    assert c.recv() == (3, 1, holding_reply(0, 1))
    assert [f[0] for _, f in received(record)] == [3, 0, 1]
    assert_counters(gw, requests=3, replies=1, timeouts=1, broadcasts=1,
                    late_bytes=len(rtu(3, holding_reply(0, 3))), unsolicited_bytes=0)


# --- frames that are not the reply ----------------------------------------------------------
# Two receive paths: FC03 is framed by libmodbus, FC 108 by mbgw's own reader (by silence).

READS = {0x03: (read_holding(0, 2), holding_reply(0, 2)),
         VENDOR_FC: (VENDOR_REQUEST, fault_slave.VENDOR_REPLY)}
BOTH_PATHS = pytest.mark.parametrize("function", sorted(READS), ids=["fc03", "fc108"])


@BOTH_PATHS
@pytest.mark.parametrize("exception", [False, True], ids=["silent", "exception"])
def test_bad_crc_reply_is_dropped(line, gateway, client, function, exception):
    line()
    gw = gateway(*(["--exception"] if exception else []))
    c = client(gw)
    c.send(mbap(1, 4, READS[function][0]), mbap(2, 1, read_holding(0, 1)))
    if exception:
        assert c.recv() == (1, 4, bytes((function | 0x80, 0x0B)))
    assert c.recv() == (2, 1, holding_reply(0, 1))
    bad_reply = rtu(4, READS[function][1])       # no frame: its bytes are noise
    assert_counters(gw, requests=2, replies=2 if exception else 1, timeouts=1, crc_errors=1,
                    gateway_exceptions=1 if exception else 0, noise_bytes=len(bad_reply))


@BOTH_PATHS
def test_reply_from_another_unit_is_dropped(line, gateway, client, function):
    line()
    gw = gateway()
    c = client(gw)
    c.send(mbap(1, 5, READS[function][0]), mbap(2, 1, read_holding(0, 1)))
    assert c.recv() == (2, 1, holding_reply(0, 1))
    assert_counters(gw, requests=2, replies=1, timeouts=1, wrong_unit=1)


def test_reply_with_another_function_is_dropped(line, gateway, client):
    line()
    gw = gateway()
    c = client(gw)
    c.send(mbap(1, 7, read_holding(0, 2)), mbap(2, 1, read_holding(0, 1)))
    assert c.recv() == (2, 1, holding_reply(0, 1))
    assert_counters(gw, requests=2, replies=1, timeouts=1, wrong_function=1)


@pytest.mark.serial
@BOTH_PATHS
def test_reply_after_a_foreign_frame_is_delivered(line, gateway, client, function):
    # FC 108 replies are framed by silence: a gateway thread that sleeps through a 5 ms gap
    # (a loaded machine) finds both frames in the buffer as one, so give it more room there.
    line(*(["--foreign-pause-ms", "30"] if function == VENDOR_FC else []))
    gw = gateway()
    c = client(gw)
    request, reply = READS[function]
    sent = time.monotonic()
    c.send(mbap(0x0808, 8, request))
    assert c.recv() == (0x0808, 8, reply)
    assert time.monotonic() - sent < STOUT_S
    assert_counters(gw, requests=1, replies=1, wrong_unit=1)


@pytest.mark.serial
@pytest.mark.parametrize("function, garbage", [
    (0x03, "55 aa 55"),        # reads as the header of an exception reply (5 bytes)
    (0x03, "00 00 00"),        # reads as a read reply with byte count 0 (5 bytes)
    (VENDOR_FC, "55 aa 55"),
    (VENDOR_FC, "00 00 00"),   # function 0: length unknown, framed by silence anyway
], ids=["fc03-exception-like", "fc03-zeros", "fc108-exception-like", "fc108-zeros"])
def test_reply_after_garbage_and_silence_is_delivered(line, gateway, client, function, garbage):
    """Noise, 60 ms of silence (>> t3.5), then the real reply, all within stout: the silence
    ends the noise's frame (Serial Line V1.02 2.5.1.1), and the reply that follows is good.
    (Both receive paths once lost it: libmodbus's byte timeout ended the transaction, and our
    own reader awaited a known length across the silence.)  60 ms rather than the peer's
    20, for a loaded machine: a gateway thread that sleeps past the start of the reply can no
    longer see the silence before it."""
    line("--garbage", garbage, "--garbage-pause-ms", "60")
    gw = gateway()
    c = client(gw)
    request, reply = READS[function]
    c.send(mbap(13, 13, request))
    assert c.recv() == (13, 13, reply)
    assert_counters(gw, requests=1, replies=1, invalid_frames=1, noise_bytes=3)


@pytest.mark.serial
@BOTH_PATHS
def test_reply_after_garbage_and_the_least_silence_is_delivered(line, gateway, client,
                                                                 function):
    """The same, with the reply 1.5 x t3.5 after the noise: at 600 bit/s t3.5 is 58.3 ms, so
    the pause is 87.5 ms, with wide margins on both sides of t3.5 and 2 x t3.5.  (The resync
    after the broken frame once waited for t3.5 of quiet from its own start, not from the
    noise's last byte, and threw away a reply that began within 2 x t3.5.)"""
    line("--garbage-pause-ms", "87.5")
    gw = gateway(baudrate=600)
    c = client(gw)
    request, reply = READS[function]
    c.send(mbap(13, 13, request))
    assert c.recv() == (13, 13, reply)
    assert_counters(gw, requests=1, replies=1, invalid_frames=1, noise_bytes=3)


# --- noise right before the reply ------------------------------------------------------------
# A glitch byte, or a few bytes of noise, in the same write as the reply (an RS-485 transceiver
# turning around): the reply is found behind them by its address, function and CRC, and what
# the line carried is counted byte for byte.  Both ways to the line: one client on an idle
# line takes the shortcut (csrc/forward.c, mbgw_take_request); with --no-shortcut every
# request goes the ordinary way (SerialMaster.transact): the gateway fixture runs both.
NOISE = [
    pytest.param("09 18 ff ff 01 02", id="fifo-header"),    # FC 0x18 claiming 65535 bytes
    pytest.param("00", id="glitch-00"),
    pytest.param("ff", id="glitch-ff"),
    pytest.param("0d", id="own-address"),                   # unit 13's address alone
    pytest.param("0d 03 20", id="own-address-and-fc"),      # ... claiming 32 data bytes
    pytest.param("0d 83", id="own-exception-header"),
]


def written(record) -> int:
    """The bytes the slave wrote on the line, from its own record."""
    return sum(len(bytes.fromhex(line.split(" ", 2)[2]))
               for line in record.read_text().splitlines() if line.split(" ", 2)[1] == "tx")


def noise_then(noise: str) -> list[str]:
    """The peer's options: noise (hex), and right behind it in one write the reply (unit 13)."""
    return ["--garbage", noise, "--garbage-pause-ms", "0"]


@pytest.mark.parametrize("noise", NOISE)
def test_reply_right_behind_noise_is_delivered(line, gateway, client, noise):
    record = line(*noise_then(noise))
    gw = gateway("--exception")
    c = client(gw)
    c.send(mbap(0x1313, 13, read_holding(0, 2)))
    assert c.recv_raw() == mbap(0x1313, 13, holding_reply(0, 2))
    assert_counters(gw, requests=1, replies=1, noise_bytes=len(bytes.fromhex(noise)),
                    bytes_received=written(record))
    assert written(record) == len(bytes.fromhex(noise)) + len(rtu(13, holding_reply(0, 2)))


@pytest.mark.parametrize("noise", ["09 18 ff ff 01 02", "00", "0d 6c"],
                         ids=["fifo-header", "glitch-00", "own-address-and-fc"])
def test_a_reply_framed_by_silence_right_behind_noise_is_delivered(line, gateway, client,
                                                                   noise):
    """FC 108's reply has no length to go by: it is the rest of the burst behind the noise."""
    record = line(*noise_then(noise))
    gw = gateway("--exception")
    c = client(gw)
    c.send(mbap(0x6C6C, 13, VENDOR_REQUEST))
    assert c.recv_raw() == mbap(0x6C6C, 13, fault_slave.VENDOR_REPLY)
    assert_counters(gw, requests=1, replies=1, noise_bytes=len(bytes.fromhex(noise)),
                    bytes_received=written(record))


@pytest.mark.parametrize("noise", [
    pytest.param("09 18 ff ff 01 02", id="fifo-header"),
    pytest.param("0f 03 20", id="own-address-and-fc"),
    pytest.param("ff" + rtu(15, holding_reply(0, 1)).hex(), id="frame-of-another-size"),
    pytest.param("ff" + rtu(15, b"\x04\x04" + bytes(4)).hex(), id="frame-of-another-fc"),
    pytest.param("ff" + rtu(9, holding_reply(0, 2)).hex(), id="frame-of-another-unit"),
])
def test_noise_alone_is_no_reply(line, gateway, client, noise):
    """Unit 15 sends the noise only.  Noise that holds a whole frame with a valid CRC is no
    reply either when that frame does not answer the request."""
    record = line("--garbage", noise)
    gw = gateway("--exception")
    c = client(gw)
    c.send(mbap(0x1515, 15, read_holding(0, 2)))
    assert c.recv_raw() == mbap(0x1515, 15, b"\x83\x0b")
    assert_counters(gw, requests=1, replies=1, timeouts=1, gateway_exceptions=1,
                    invalid_frames=1, noise_bytes=len(bytes.fromhex(noise)),
                    bytes_received=written(record))


@pytest.mark.parametrize("frame", [
    pytest.param(rtu(13, holding_reply(0, 1)), id="another-size"),
    pytest.param(rtu(13, b"\x04\x04" + bytes(4)), id="another-fc"),
    pytest.param(rtu(9, holding_reply(0, 2)), id="another-unit"),
])
def test_a_frame_inside_the_noise_is_not_taken_for_the_reply(line, gateway, client,
                                                              frame):
    """A glitch, a whole frame with a valid CRC that does not answer, then the reply."""
    noise = "ff" + frame.hex()
    record = line(*noise_then(noise))
    gw = gateway("--exception")
    c = client(gw)
    c.send(mbap(0x1313, 13, read_holding(0, 2)))
    assert c.recv_raw() == mbap(0x1313, 13, holding_reply(0, 2))
    assert_counters(gw, requests=1, replies=1, noise_bytes=1 + len(frame),
                    bytes_received=written(record))


@pytest.mark.parametrize("frame, counted", [
    pytest.param(rtu(13, b"\x04\x04" + bytes(4)), "wrong_function", id="another-fc"),
    pytest.param(rtu(9, holding_reply(0, 2)), "wrong_unit", id="another-unit"),
])
def test_a_frame_right_before_the_reply_is_counted_and_dropped(line, gateway, client,
                                                                frame, counted):
    """A whole frame that does not answer, and the reply right behind it in one write: the
    frame is one (counted as such, no noise) and the reply is still found."""
    record = line(*noise_then(frame.hex()))
    gw = gateway("--exception")
    c = client(gw)
    c.send(mbap(0x1313, 13, read_holding(0, 2)))
    assert c.recv_raw() == mbap(0x1313, 13, holding_reply(0, 2))
    assert_counters(gw, requests=1, replies=1, bytes_received=written(record), **{counted: 1})


def test_a_run_with_noise_before_every_reply_counts_what_the_line_carried(line, gateway,
                                                                          client):
    """The issue's run, shorter: before the fix, 2,000 requests counted 87,014 bytes received
    for 40,216 written, and replies were lost."""
    noise = bytes.fromhex("09 18 ff ff 01 02")
    record = line(*noise_then(noise.hex()))
    gw = gateway("--exception")
    c = client(gw)
    runs = 40
    for i in range(runs):
        assert c.ask(13, read_holding(i, 3)) == holding_reply(i, 3)
    assert_counters(gw, requests=runs, replies=runs, noise_bytes=runs * len(noise),
                    bytes_received=written(record))
    assert written(record) == runs * (len(noise) + len(rtu(13, holding_reply(0, 3))))


# --- pass-through ---------------------------------------------------------------------------

def test_vendor_function_108_passes_through_byte_exact(line, gateway, client):
    record = line()
    gw = gateway()
    c = client(gw)
    c.send(mbap(0x6C6C, 10, VENDOR_REQUEST))
    reply = c.recv_raw()
    assert reply == struct.pack(">HHHB", 0x6C6C, 0, 1 + len(fault_slave.VENDOR_REPLY), 10) \
        + fault_slave.VENDOR_REPLY
    assert [f for _, f in received(record)] == [rtu(10, VENDOR_REQUEST)]
    assert_counters(gw, requests=1, replies=1)


def test_device_exception_passes_through_unchanged(line, gateway, client):
    line()
    gw = gateway("--exception")
    c = client(gw)
    c.send(mbap(0x1111, 11, read_holding(0, 1)))
    assert c.recv_raw() == b"\x11\x11\x00\x00\x00\x03\x0b\x83\x02"
    assert_counters(gw, requests=1, replies=1, device_exceptions=1)


# --- retries --------------------------------------------------------------------------------

def test_retry_gets_the_answer_of_a_slave_that_missed_the_first_request(line, gateway, client):
    record = line()
    gw = gateway("--retries", "1")
    c = client(gw)
    c.send(mbap(12, 12, read_holding(0, 2)))
    assert c.recv() == (12, 12, holding_reply(0, 2))
    frames = received(record)
    assert [f for _, f in frames] == [rtu(12, read_holding(0, 2))] * 2
    # the retry waited for stout (less the jitter of the peer's arrival times)
    assert frames[1][0] - frames[0][0] >= STOUT_S - 0.03
    assert_counters(gw, requests=1, replies=1, retries=1)


def test_without_retries_the_missed_request_gets_no_answer(line, gateway, client):
    record = line()
    gw = gateway()
    c = client(gw)
    c.send(mbap(12, 12, read_holding(0, 2)), mbap(1, 1, read_holding(0, 1)))
    assert c.recv() == (1, 1, holding_reply(0, 1))
    assert [f[0] for _, f in received(record)] == [12, 1]
    assert_counters(gw, requests=2, replies=1, timeouts=1)


# --- addressing -----------------------------------------------------------------------------

@pytest.mark.serial
def test_broadcast_reaches_the_line_unanswered_and_holds_the_line_for_turnaround(
        line, gateway, client):
    record = line()
    gw = gateway("--turnaround", "300", "--exception")
    c = client(gw)
    c.send(mbap(1, 0, b"\x06\x00\x01\x00\x2a"), mbap(2, 1, read_holding(0, 1)))
    assert c.recv() == (2, 1, holding_reply(0, 1))
    frames = received(record)
    assert [f for _, f in frames] == [rtu(0, b"\x06\x00\x01\x00\x2a"),
                                      rtu(1, read_holding(0, 1))]
    gap = frames[1][0] - frames[0][0]      # 300 ms, less the jitter of the arrival times
    assert 0.27 <= gap < 0.6, gap
    assert_counters(gw, requests=2, replies=1, broadcasts=1)


@pytest.mark.serial
def test_a_request_on_the_idle_line_after_a_broadcast_still_waits_for_turnaround(
        line, gateway, client):
    """The broadcast is out and the line idle when the next request comes: it is read and
    sent by the same thread at once, yet not before the turnaround has passed."""
    record = line()
    gw = gateway("--turnaround", "300")
    c = client(gw)
    c.send(mbap(1, 0, b"\x06\x00\x01\x00\x2a"))
    wait_for(gw, lambda s: s["counters"]["broadcasts"] == 1, "sent the broadcast")
    c.send(mbap(2, 1, read_holding(0, 1)))
    assert c.recv() == (2, 1, holding_reply(0, 1))
    frames = received(record)
    assert [f[0] for _, f in frames] == [0, 1]
    assert 0.27 <= frames[1][0] - frames[0][0] < 0.6


def test_slaveid_forces_the_serial_address_and_keeps_the_clients_unit(line, gateway, client):
    record = line()
    gw = gateway("--slaveid", "1")
    c = client(gw)
    c.send(mbap(0x4D4D, 77, read_holding(2, 2)))
    assert c.recv() == (0x4D4D, 77, holding_reply(2, 2))
    assert [f for _, f in received(record)] == [rtu(1, read_holding(2, 2))]
    assert_counters(gw, requests=1, replies=1)


@pytest.mark.parametrize("exception", [False, True])
def test_reserved_units_never_reach_the_line(line, gateway, client, exception):
    record = line()
    gw = gateway(*(["--exception"] if exception else []))
    c = client(gw)
    c.send(*(mbap(unit, unit, read_holding(0, 1)) for unit in range(248, 256)),
           mbap(1, 1, read_holding(0, 1)))
    if exception:
        for unit in range(248, 256):
            assert c.recv() == (unit, unit, b"\x83\x0a")
    assert c.recv() == (1, 1, holding_reply(0, 1))
    assert [f for _, f in received(record)] == [rtu(1, read_holding(0, 1))]
    assert_counters(gw, requests=9, replies=9 if exception else 1, unroutable=8,
                    gateway_exceptions=8 if exception else 0)


# --- stopping -------------------------------------------------------------------------------

def fill(path: str) -> None:
    """Fill the queue of the notify socket at path, as a reader that does not read would."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as filler:
        filler.setblocking(False)
        try:
            while True:
                filler.sendto(b"FILLER=1", path)
        except BlockingIOError:
            pass


def start_notifying(pty_pair, path: str, log_path: Path) -> subprocess.Popen:
    """`mbgw slave` on the pair's gateway end, telling its states to the socket at path."""
    with open(log_path, "w") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "mbgw", "slave", "--device", pty_pair.gateway,
             "--bind", "127.0.0.1", "--mdbport", str(free_port())],
            env=dict(os.environ, NOTIFY_SOCKET=path), stdout=log, stderr=log)


def test_sigterm_as_ready_goes_out_stops_cleanly(pty_pair, tmp_path):
    """systemd may stop a unit as soon as READY=1 is in, so the SIGTERM handler must already
    be in place (it once came after READY=1: the default action killed the gateway, status
    -15, no counters).  Made deterministic: the notify socket's queue is full, so the gateway
    blocks in its sendto(READY=1); SIGTERM comes then, and only then is the queue drained."""
    path = str(tmp_path / "notify")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(path)
    fill(path)
    log_path = tmp_path / "mbgw.log"
    proc = start_notifying(pty_pair, path, log_path)
    try:
        # no event exists for "blocked in sendto": poll the kernel's wait channel
        until(lambda: proc.poll() is not None
              or Path(f"/proc/{proc.pid}/wchan").read_text() == "unix_wait_for_peer",
              lambda: f"blocked in sendto: {log_path.read_text()}", READY_TIMEOUT_S)
        assert proc.poll() is None, log_path.read_text()
        proc.send_signal(signal.SIGTERM)
        notify.setblocking(False)
        said = []
        try:
            while True:
                said.append(notify.recv(4096))
        except BlockingIOError:
            pass
        assert proc.wait(READY_TIMEOUT_S) == 0, log_path.read_text()
        assert "stopped; counters:" in log_path.read_text()
    finally:
        stop(proc)
        notify.close()


def test_a_notify_socket_nobody_reads_does_not_keep_the_gateway_from_stopping(pty_pair,
                                                                             tmp_path):
    """A notify socket whose queue is full (a supervisor that has stopped reading, or the
    STATUS= lines of a long run nobody reads) holds STOPPING=1 for 2 s at most: SIGTERM still
    stops the gateway, with its counters."""
    path = str(tmp_path / "notify")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(path)
    log_path = tmp_path / "mbgw.log"
    proc = start_notifying(pty_pair, path, log_path)
    try:
        notify.settimeout(READY_TIMEOUT_S)
        while b"READY=1" not in notify.recv(4096):
            pass
        fill(path)                         # full: nobody reads any more
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(READY_TIMEOUT_S) == 0, log_path.read_text()
        assert "stopped; counters:" in log_path.read_text()
    finally:
        stop(proc)
        notify.close()


# --- the late window: a late reply never reaches the next request to its address ------------

LATE_MS = 250           # the slave's unit 17 answers its first request 50 ms after stout


def sent_by_peer(record, frame: bytes) -> list[float]:
    """When the slave wrote frame (its record's tx lines)."""
    return [float(row.split()[0]) for row in record.read_text().splitlines()
            if row.split()[1] == "tx" and row.endswith(frame.hex(" "))]


def peer_of(c) -> str:
    """A client's address as the trace shows it."""
    host, port = c.sock.getsockname()[:2]
    return f"{host}:{port}"


def wait_received(record, count: int) -> None:
    """Until the slave has received count frames (its record is written as they come)."""
    until(lambda: len(received(record)) >= count,
          lambda: f"{count} frames received: {record.read_text()}", READY_TIMEOUT_S)


@pytest.mark.serial
@pytest.mark.parametrize("exception", [False, True], ids=["silent", "exception"])
def test_a_late_reply_never_reaches_another_clients_request_to_the_same_unit(
        line, gateway, client, exception):
    """A reads 2 registers at 0 of unit 17 and times out (the slave, busy, answers 250 ms after
    the request, stout 200 ms).  B's read of 2 registers at 50 of unit 17 (a reply of the same
    size) waits for unit 17's late window: A's late reply comes, is dropped and counted, and
    only then B's request goes out; B gets its own registers (without the window, B's request
    went out at A's timeout and got A's registers).  C's request to unit 1, queued behind B,
    does not wait: it goes on the line right after A's timeout."""
    record = line("--late-ms", str(LATE_MS))
    gw = gateway(*(["--exception"] if exception else []))
    a, b, c = client(gw), client(gw), client(gw)
    a.send(mbap(1, 17, read_holding(0, 2)))
    wait_received(record, 1)
    b.send(mbap(2, 17, read_holding(50, 2)))
    c.send(mbap(3, 1, read_holding(0, 1)))
    assert c.recv() == (3, 1, holding_reply(0, 1))
    assert b.recv() == (2, 17, holding_reply(50, 2))
    assert a.recv(0.01 if not exception else None) == \
        ((1, 17, b"\x83\x0b") if exception else None)
    frames = received(record)
    assert [f for _, f in frames] == [rtu(17, read_holding(0, 2)), rtu(1, read_holding(0, 1)),
                                      rtu(17, read_holding(50, 2))]
    late = sent_by_peer(record, rtu(17, holding_reply(0, 2)))
    assert len(late) == 1 and frames[1][0] < late[0] < frames[2][0]
    assert_counters(gw, requests=3, replies=3 if exception else 2, timeouts=1,
                    gateway_exceptions=1 if exception else 0, late_replies=1)


@pytest.mark.serial
def test_a_retry_takes_the_late_reply_to_its_first_try_and_the_window_waits_for_its_own(
        line, gateway, client, tmp_path):
    """With --retries 1, A's first try times out and the retry goes at once: the first try's
    late reply, coming during the retry, answers it (the same request, so the same answer).
    The retry's own reply is still to come: unit 17's late window waits for it, so B's request
    goes out only once it has come and been dropped (counted, and traced with A's request);
    B gets its own registers."""
    record = line("--late-ms", str(LATE_MS))
    gw = gateway("--retries", "1")
    a, b = client(gw), client(gw)
    with tracing(gw, tmp_path / "trace.pcap", count=5) as (trace, _):
        a.send(mbap(1, 17, read_holding(0, 2)))
        assert a.recv() == (1, 17, holding_reply(0, 2))
        b.send(mbap(2, 17, read_holding(50, 2)))
        assert b.recv() == (2, 17, holding_reply(50, 2))
        out, err = trace.communicate(timeout=10)
    assert trace.returncode == 0, err
    late = [line.split()[1:] for line in out.decode().splitlines() if " late " in line]
    assert late == [["late", peer_of(a), "1", "17", "0x03", "6", "late", "reply,", "dropped"]]
    frames = received(record)
    assert [f for _, f in frames] == [rtu(17, read_holding(0, 2))] * 2 + \
        [rtu(17, read_holding(50, 2))]
    replies_to_a = sent_by_peer(record, rtu(17, holding_reply(0, 2)))
    assert len(replies_to_a) == 2 and replies_to_a[1] < frames[2][0]
    assert_counters(gw, requests=2, replies=2, retries=1, late_replies=1)


@pytest.mark.serial
def test_a_silent_units_window_ends_when_the_line_has_been_quiet_for_late_window(
        line, gateway, client):
    """Unit 2 never answers: after A's timeout, B's request to it waits until the line has been
    quiet for --late-window (100 ms) past A's deadline, then goes; unit 1's request, sent
    after B, does not wait."""
    record = line()
    gw = gateway("--late-window", "100")
    a, b, c = client(gw), client(gw), client(gw)
    a.send(mbap(1, 2, read_holding(0, 1)))
    wait_received(record, 1)
    b.send(mbap(2, 2, read_holding(0, 1)))
    c.send(mbap(3, 1, read_holding(0, 1)))
    assert c.recv() == (3, 1, holding_reply(0, 1))
    wait_received(record, 3)
    frames = received(record)
    assert [f[0] for _, f in frames] == [2, 1, 2]
    # B went out late-window (100 ms) after A's timeout, unit 1's request right at it (the
    # slave dates each frame as it wakes up for it: a few ms of margin either way)
    assert frames[2][0] - frames[0][0] > (STOUT_MS + 50) / 1000
    assert frames[1][0] - frames[0][0] < (STOUT_MS + 50) / 1000
    assert_counters(gw, requests=3, replies=1, timeouts=2)
