"""The C receive that hands a reply straight to its client's socket (csrc/forward.c): a reply
that answers the request goes out at once as the client's Modbus TCP frame; one that does not
never reaches the socket.  The exchange writes the request and receives in one call.  A real
pty pair carries the slave's frames; the expected bytes come from tests/modbus.py's builders,
not from mbgw."""
import errno
import os
import socket
import threading
import time

import pytest
from mbgw._ffi import ffi, lib

from mbgw.errors import FrameError, LineTimeout
from mbgw.line.native import NO_COUNTER, REPLY_AT, REPLY_SCAN, Forward, Port, counter
from tests.modbus import holding_reply, mbap, read_holding, rtu

pytestmark = pytest.mark.integration

UNIT, TID, CLIENT_UNIT = 17, 0x1234, 99
REQUEST = bytes((UNIT,)) + read_holding(0, 3)


@pytest.fixture
def line(pty_pair):
    """(Port on the gateway's end, fd of the slave's end)."""
    port = Port(pty_pair.gateway, 19200, "n", 8, 1)
    port.set_byte_timeout(2000)
    slave = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)
    yield port, slave
    os.close(slave)
    port.close()


def to(sock: socket.socket, yield_cpu: bool = False, in_flight=NO_COUNTER) -> Forward:
    """The reply's way to the client at sock, as TID and CLIENT_UNIT."""
    return Forward(sock.fileno(), TID, CLIENT_UNIT, yield_cpu, in_flight)


def deadline(seconds: float = 1.0) -> int:
    return time.monotonic_ns() + int(seconds * 1e9)


def nothing_on(sock: socket.socket) -> bool:
    sock.setblocking(False)
    try:
        return not sock.recv(1024)
    except BlockingIOError:
        return True


def test_a_reply_that_answers_goes_to_the_client_at_once(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    in_flight = counter()
    in_flight[0] = 1
    os.write(slave, rtu(UNIT, holding_reply(0, 3)))
    got = port.receive_reply(REQUEST, deadline(), to(ours, True, in_flight))
    assert got.frame == bytes((UNIT,)) + holding_reply(0, 3)
    expected = mbap(TID, CLIENT_UNIT, holding_reply(0, 3))
    assert got.forwarded == len(expected)
    assert theirs.recv(1024) == expected
    assert in_flight[0] == 0      # answered as it was sent


def test_a_device_exception_is_an_answer_too(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    os.write(slave, rtu(UNIT, b"\x83\x02"))
    assert port.receive_reply(REQUEST, deadline(), to(ours)).frame
    assert theirs.recv(1024) == mbap(TID, CLIENT_UNIT, b"\x83\x02")


@pytest.mark.parametrize("reply", [
    holding_reply(0, 2),                    # two registers where three were asked for
    b"\x04\x06" + bytes(6),                 # another function
    b"\x84\x02",                            # an exception for another function
], ids=["wrong size", "wrong function", "wrong exception"])
def test_a_reply_that_does_not_answer_never_reaches_the_client(line, socket_ends, reply):
    port, slave = line
    ours, theirs = socket_ends
    in_flight = counter()
    in_flight[0] = 1
    os.write(slave, rtu(UNIT, reply))
    got = port.receive_reply(REQUEST, deadline(), to(ours, False, in_flight))
    assert got.frame == bytes((UNIT,)) + reply
    assert got.forwarded == -1
    assert nothing_on(theirs)
    assert in_flight[0] == 1


def test_a_frame_from_another_address_is_dropped_unsent(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    os.write(slave, rtu(UNIT + 1, holding_reply(0, 3)))
    got = port.receive_reply(REQUEST, deadline(), to(ours))
    assert got.frame is None
    assert got.foreign_address == UNIT + 1
    assert got.forwarded == -1
    assert nothing_on(theirs)


@pytest.mark.parametrize("noise", ["00", "ff", "11 03 20", "09 18 ff ff 01 02"])
def test_a_reply_behind_noise_goes_to_the_client_and_the_noise_is_counted(line, socket_ends,
                                                                          noise):
    port, slave = line
    ours, theirs = socket_ends
    os.write(slave, bytes.fromhex(noise) + rtu(UNIT, holding_reply(0, 3)))
    got = port.receive_reply(REQUEST, deadline(), to(ours))
    assert got.frame == bytes((UNIT,)) + holding_reply(0, 3)
    assert theirs.recv(1024) == mbap(TID, CLIENT_UNIT, holding_reply(0, 3))
    assert got.noise == len(bytes.fromhex(noise))


def test_a_frame_right_behind_a_foreign_one_stays_for_the_next_receive(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    os.write(slave, rtu(UNIT + 1, b"\x83\x02") + rtu(UNIT, holding_reply(0, 3)))
    got = port.receive_reply(REQUEST, deadline(), to(ours))
    assert got.frame is None
    assert (got.foreign_address, got.length, got.noise) == (UNIT + 1, 5, 0)
    assert nothing_on(theirs)
    assert port.receive_reply(REQUEST, deadline()).frame == bytes((UNIT,)) + holding_reply(0, 3)


def test_noise_alone_is_counted_and_sends_nothing(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    os.write(slave, bytes.fromhex("09 18 ff ff 01 02"))
    got = port.receive_reply(REQUEST, deadline(), to(ours))
    assert isinstance(got.fault, FrameError)
    assert got.noise == 6
    assert nothing_on(theirs)


def test_a_full_client_socket_takes_nothing_and_loses_nothing(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    while True:
        try:
            ours.send(bytes(4096))
        except BlockingIOError:
            break
    os.write(slave, rtu(UNIT, holding_reply(0, 3)))
    got = port.receive_reply(REQUEST, deadline(), to(ours))
    assert got.frame == bytes((UNIT,)) + holding_reply(0, 3)
    assert got.forwarded == 0     # the caller sends the whole reply later, behind what waits


def test_without_a_client_nothing_is_sent(line):
    port, slave = line
    os.write(slave, rtu(UNIT, holding_reply(0, 3)))
    got = port.receive_reply(REQUEST, deadline())
    assert got.frame == bytes((UNIT,)) + holding_reply(0, 3)
    assert got.forwarded == -1


def test_no_reply_by_the_deadline_is_a_timeout(line, socket_ends):
    port, _ = line
    ours, theirs = socket_ends
    got = port.receive_reply(REQUEST, deadline(0.05), to(ours))
    assert isinstance(got.fault, LineTimeout)
    assert nothing_on(theirs)


CHAR_NS = 10 * 1_000_000_000 // 19200


def answer_once(slave: int, reply: bytes) -> tuple[threading.Thread, list]:
    """A slave that reads one request and answers it; the request read goes to the list."""
    got = []

    def serve():
        request = b""
        while len(request) < len(REQUEST) + 2:
            request += os.read(slave, 256)
        got.append(request)
        os.write(slave, reply)
    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return thread, got


def test_the_exchange_writes_the_request_and_forwards_its_reply(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    thread, got = answer_once(slave, rtu(UNIT, holding_reply(0, 3)))
    before = time.monotonic_ns()
    reply = port.exchange(REQUEST, CHAR_NS, 1_000_000_000, to(ours))
    thread.join(1)
    assert got == [rtu(UNIT, read_holding(0, 3))]
    assert reply.frame == bytes((UNIT,)) + holding_reply(0, 3)
    assert theirs.recv(1024) == mbap(TID, CLIENT_UNIT, holding_reply(0, 3))
    # the request's last byte leaves 8 characters after the write began
    assert before + 8 * CHAR_NS <= reply.request_end_ns <= reply.last_byte_ns + 8 * CHAR_NS


def test_the_exchange_waits_stout_from_the_end_of_the_request(line, socket_ends):
    port, slave = line
    ours, theirs = socket_ends
    got = port.exchange(REQUEST, CHAR_NS, 50_000_000, to(ours))
    assert isinstance(got.fault, LineTimeout)
    assert got.last_byte_ns >= got.request_end_ns + 50_000_000
    assert os.read(slave, 256) == rtu(UNIT, read_holding(0, 3))
    assert nothing_on(theirs)



def test_a_receive_on_a_context_without_a_line_fails_at_once():
    """modbus_get_socket gives -1 for a libmodbus context with no line open: an error of
    the line (-EBADF), not a slave that stays silent until the deadline."""
    ctx = lib.modbus_new_rtu(b"/dev/null", 19200, b"N", 8, 1)      # never connected
    buf = ffi.new("uint8_t[]", REPLY_AT + REPLY_SCAN)
    nowhere = ffi.new("struct mbgw_forward *", {"fd": -1})
    end_ns, sent, noise = ffi.new("int64_t *"), ffi.new("int *"), ffi.new("int *")
    try:
        rc = lib.mbgw_receive_reply(ctx, buf, REQUEST, len(REQUEST), deadline(5.0), 2000,
                                    nowhere, end_ns, sent, noise)
    finally:
        lib.modbus_free(ctx)
    assert rc == -errno.EBADF
    assert sent[0] == -1 and noise[0] == 0
