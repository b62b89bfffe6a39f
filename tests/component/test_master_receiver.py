"""Master mode's serial receiver (csrc/request.c through native.Port.read_request) on a plain
pty pair: the test writes what a serial master and the other slaves of the bus would, often
several frames in one write, and checks the frames come out one by one, unchanged."""
import os
import threading
import time

import pytest

from mbgw.errors import ChecksumError, FrameError, SerialError
from mbgw.line import native
from tests.modbus import rtu_frame as rtu

pytestmark = pytest.mark.integration

GAP_US = 20_000         # end-of-frame silence; a pty delivers each write whole, well within it
OTHER = 50              # a slave on the bus that mbgw does not stand for


READ_17 = bytes.fromhex("11 03 006b 0003")
READ_OTHER = bytes((OTHER,)) + bytes.fromhex("03 0000 0002")
OTHER_REPLY = bytes((OTHER,)) + bytes.fromhex("03 04 0001 0002")
WRITE_OTHER = bytes((OTHER,)) + bytes.fromhex("10 0001 0002 04 000a 000b")
WRITE_OTHER_REPLY = bytes((OTHER,)) + bytes.fromhex("10 0001 0002")
OTHER_EXCEPTION = bytes((OTHER,)) + bytes.fromhex("83 02")


@pytest.fixture
def line():
    """(fd the test writes to as the bus, Port mbgw reads from)."""
    bus, tty = os.openpty()
    port = native.Port(os.ttyname(tty), 19200, "n", 8, 1)
    os.close(tty)
    yield bus, port
    port.close()
    os.close(bus)


def test_a_request_for_any_address(line, wake_fd):
    bus, port = line
    for address in (1, 17, 247, 255):
        adu = bytes((address,)) + READ_17[1:]
        os.write(bus, rtu(adu))
        assert port.read_request(wake_fd, b"", GAP_US) == adu


@pytest.mark.parametrize("request_adu, reply_adu", [
    (READ_OTHER, OTHER_REPLY),              # the reply is longer than the request
    (WRITE_OTHER, WRITE_OTHER_REPLY),       # the reply is shorter
    (READ_OTHER, OTHER_EXCEPTION),
], ids=["fc03", "fc10", "exception"])
def test_another_slaves_request_and_reply_then_ours_in_one_burst(line, wake_fd, request_adu,
                                                                  reply_adu):
    bus, port = line
    os.write(bus, rtu(request_adu) + rtu(reply_adu) + rtu(READ_17))
    assert port.read_request(wake_fd, b"", GAP_US) == request_adu
    assert port.read_request(wake_fd, request_adu, GAP_US) == reply_adu
    assert port.read_request(wake_fd, reply_adu, GAP_US) == READ_17


def test_the_request_after_an_unanswered_one_is_still_a_request(line, wake_fd):
    """The other slave is absent: the master repeats its request, then polls 17."""
    bus, port = line
    os.write(bus, rtu(READ_OTHER) + rtu(READ_OTHER) + rtu(READ_17))
    assert port.read_request(wake_fd, b"", GAP_US) == READ_OTHER
    assert port.read_request(wake_fd, READ_OTHER, GAP_US) == READ_OTHER
    assert port.read_request(wake_fd, READ_OTHER, GAP_US) == READ_17


def test_each_function_codes_request_length(line, wake_fd):
    bus, port = line
    requests = [bytes.fromhex(h) for h in (
        "11 01 0013 0025", "11 05 00ac ff00", "11 07", "11 08 000a 0000",
        "11 0f 0013 000a 02 cd01", "11 16 0004 00f2 0025",
        "11 17 0003 0006 000e 0003 06 00ff 00ff 00ff", "11 18 04de", "11 2b 0e 01 00",
        "11 0b", "11 14 0e 06 0004 0001 0000 0002")]
    os.write(bus, b"".join(rtu(r) for r in requests))
    assert [port.read_request(wake_fd, b"", GAP_US) for _ in requests] == requests


@pytest.mark.parametrize("adu", [bytes.fromhex("11 6c 07 01 00"),
                                 bytes.fromhex("11 08 0000 0102 0304 0506")],
                         ids=["vendor-fc108", "fc08-00-echo"])
def test_a_request_of_unknown_length_ends_with_silence(line, wake_fd, adu):
    bus, port = line
    os.write(bus, rtu(adu))
    started = time.monotonic()
    assert port.read_request(wake_fd, b"", GAP_US) == adu
    assert time.monotonic() - started >= GAP_US / 1e6


def test_a_bad_crc_is_reported_and_the_next_frame_is_read(line, wake_fd):
    bus, port = line
    os.write(bus, READ_17 + b"\x00\x00")
    with pytest.raises(ChecksumError):
        port.read_request(wake_fd, b"", GAP_US)
    os.write(bus, rtu(READ_17))
    assert port.read_request(wake_fd, b"", GAP_US) == READ_17


NOISE = [
    pytest.param("ff", id="glitch-ff"),
    pytest.param("00", id="glitch-00"),
    pytest.param("11", id="the-address"),
    pytest.param("09 18 ff ff 01 02", id="fifo-header"),          # FC 0x18 claiming 65 KB
    pytest.param("11 10 00 00 00 10 20", id="long-write-header"),  # claims 41 bytes
]


@pytest.mark.parametrize("noise", NOISE)
def test_noise_right_before_a_request_is_skipped(line, wake_fd, noise):
    bus, port = line
    os.write(bus, bytes.fromhex(noise) + rtu(READ_17))
    assert port.read_request(wake_fd, b"", GAP_US) == READ_17
    os.write(bus, rtu(READ_17))                 # and the next frame comes out as it is
    assert port.read_request(wake_fd, b"", GAP_US) == READ_17


def test_noise_right_before_another_slaves_reply_is_skipped(line, wake_fd):
    bus, port = line
    os.write(bus, rtu(READ_OTHER))
    assert port.read_request(wake_fd, b"", GAP_US) == READ_OTHER
    os.write(bus, b"\xff" + rtu(OTHER_REPLY))
    assert port.read_request(wake_fd, READ_OTHER, GAP_US) == OTHER_REPLY


def test_noise_alone_is_still_a_bad_frame(line, wake_fd):
    bus, port = line
    os.write(bus, bytes.fromhex("09 18 ff ff 01 02"))
    with pytest.raises(ChecksumError):
        port.read_request(wake_fd, b"", GAP_US)


def test_a_frame_broken_by_silence_is_dropped(line, wake_fd):
    bus, port = line
    os.write(bus, READ_17[:2])
    with pytest.raises(FrameError):
        port.read_request(wake_fd, b"", GAP_US)
    os.write(bus, rtu(READ_17))
    assert port.read_request(wake_fd, b"", GAP_US) == READ_17


def test_a_frame_longer_than_an_rtu_adu_is_refused_whole(line, wake_fd):
    bus, port = line
    os.write(bus, bytes.fromhex("11 6c") + bytes(300))
    with pytest.raises(FrameError):
        port.read_request(wake_fd, b"", GAP_US)
    os.write(bus, rtu(READ_17))
    assert port.read_request(wake_fd, b"", GAP_US) == READ_17


def test_the_eventfd_ends_the_wait(line, wake_fd):
    _bus, port = line
    threading.Timer(0.05, os.eventfd_write, (wake_fd, 1)).start()
    started = time.monotonic()
    assert port.read_request(wake_fd, b"", GAP_US) is None
    assert time.monotonic() - started < 2


def test_idle_ms_ends_a_wait_with_nothing_on_the_line_and_keeps_the_next_frame(line, wake_fd):
    """The watchdog's idle limit: the thread's loop turns while the line is silent."""
    bus, port = line
    assert port.read_request(wake_fd, b"", GAP_US, idle_ms=20) is None
    os.write(bus, rtu(READ_17))
    assert port.read_request(wake_fd, b"", GAP_US, idle_ms=20) == READ_17


def test_a_device_that_goes_away_is_a_serial_error():
    bus, tty = os.openpty()
    port = native.Port(os.ttyname(tty), 19200, "n", 8, 1)
    os.close(tty)
    wake = os.eventfd(0)
    try:
        os.close(bus)
        with pytest.raises(SerialError):
            port.read_request(wake, b"", GAP_US)
    finally:
        port.close()
        os.close(wake)



# ---- ASCII: the reader in csrc/line.c, called as master.serial_face.SerialFace does ----

ASCII_TIMEOUT_US = 200_000


def read_ascii(port: native.Port, wake_fd: int) -> bytes | None:
    if port.idle_wait(wake_fd, -1) != 1:
        return None
    return port.read_ascii(time.monotonic_ns() + 2_000_000_000, ASCII_TIMEOUT_US).frame


def test_ascii_frames_in_one_burst_come_out_one_by_one(line, wake_fd):
    bus, port = line
    sent = [native.ascii_encode(adu) for adu in (READ_OTHER, OTHER_REPLY, READ_17,
                                                 bytes.fromhex("11 07"))]
    os.write(bus, b"noise" + b"".join(sent))
    assert [read_ascii(port, wake_fd) for _ in sent] == sent


def test_the_eventfd_ends_the_ascii_wait(line, wake_fd):
    _bus, port = line
    threading.Timer(0.05, os.eventfd_write, (wake_fd, 1)).start()
    assert read_ascii(port, wake_fd) is None
