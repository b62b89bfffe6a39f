"""The shortcut for a request that finds the line idle (csrc/forward.c, mbgw_take_request): C
reads the client and, when what came is exactly one request the line can take as it is, puts
it on the line and forwards its reply at once; anything else is left, whole and unsent, to
the Python path.  A real pty pair carries the frames; the expected bytes come from
tests/modbus.py's builders, not from mbgw."""
import errno
import os
import struct
import threading
import time
from array import array

import pytest

from mbgw.errors import LineTimeout
from mbgw.line.native import Port, counter
from mbgw.protocol import pdu
from tests.modbus import holding_reply, mbap, read_holding, rtu

pytestmark = pytest.mark.integration

UNIT, TID = 17, 0x4321
CHAR_NS = 10 * 1_000_000_000 // 19200
STOUT_NS = 1_000_000_000
REQUEST = mbap(TID, UNIT, read_holding(0, 3))


def make_port(device: str, slaveid: int = 0, down: bytearray | None = None,
              late_until: array | None = None) -> Port:
    port = Port(device, 19200, "n", 8, 1)
    port.set_byte_timeout(2000)
    port.shortcut_rules(pdu.LIBMODBUS_FRAMED, CHAR_NS, STOUT_NS, slaveid,
                        bytearray(256) if down is None else down,
                        array("q", bytes(8 * 256)) if late_until is None else late_until)
    return port


@pytest.fixture
def line(pty_pair):
    """(a function making the Port on the gateway's end, fd of the slave's end)."""
    ports = []
    slave = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)

    def port(slaveid: int = 0, down: bytearray | None = None,
             late_until: array | None = None) -> Port:
        ports.append(make_port(pty_pair.gateway, slaveid, down, late_until))
        return ports[-1]
    yield port, slave
    os.close(slave)
    for p in ports:
        p.close()


def slave_answers(slave: int, address: int, reply: bytes) -> list:
    """A slave that reads one request (8 bytes: FC03) and answers it as address; the
    request read goes to the list returned."""
    got = []

    def serve():
        request = b""
        while len(request) < 8:
            request += os.read(slave, 256)
        got.append(request)
        os.write(slave, rtu(address, reply))
    threading.Thread(target=serve, daemon=True).start()
    return got


def nothing_written(slave: int) -> bool:
    os.set_blocking(slave, False)
    try:
        return not os.read(slave, 256)
    except BlockingIOError:
        return True
    finally:
        os.set_blocking(slave, True)


def test_one_whole_request_goes_to_the_line_and_its_reply_to_the_client(line, socket_ends):
    make, slave = line
    port = make()
    ours, theirs = socket_ends
    got = slave_answers(slave, UNIT, holding_reply(0, 3))
    theirs.sendall(REQUEST)
    in_flight = counter()
    in_flight[0] = 1                # the caller's mark, made before the call
    take = port.take_request(ours.fileno(), 0, in_flight)
    assert (take.status, take.taken) == (len(REQUEST), True)
    assert in_flight[0] == 0        # answered as the reply was sent
    assert take.input == REQUEST
    assert port.exchanged().frame == bytes((UNIT,)) + holding_reply(0, 3)
    assert got == [rtu(UNIT, read_holding(0, 3))]
    assert theirs.recv(1024) == mbap(TID, UNIT, holding_reply(0, 3))
    assert take.forwarded == len(mbap(TID, UNIT, holding_reply(0, 3)))


def test_slaveid_sets_the_serial_address_and_the_client_keeps_its_unit(line, socket_ends):
    make, slave = line
    port = make(slaveid=UNIT)
    ours, theirs = socket_ends
    got = slave_answers(slave, UNIT, holding_reply(0, 3))
    theirs.sendall(mbap(TID, 99, read_holding(0, 3)))
    assert port.take_request(ours.fileno(), 0).taken
    assert port.exchanged().frame == bytes((UNIT,)) + holding_reply(0, 3)
    assert got == [rtu(UNIT, read_holding(0, 3))]
    assert theirs.recv(1024) == mbap(TID, 99, holding_reply(0, 3))


def test_no_reply_leaves_the_client_without_one(line, socket_ends):
    make, slave = line
    port = make()
    port.shortcut_rules(pdu.LIBMODBUS_FRAMED, CHAR_NS, 50_000_000, 0, bytearray(256),
                        array("q", bytes(8 * 256)))
    ours, theirs = socket_ends
    theirs.sendall(REQUEST)
    assert port.take_request(ours.fileno(), 0).taken
    got = port.exchanged()
    assert isinstance(got.fault, LineTimeout)
    assert got.last_byte_ns >= got.request_end_ns + 50_000_000
    assert os.read(slave, 256) == rtu(UNIT, read_holding(0, 3))
    theirs.setblocking(False)
    with pytest.raises(BlockingIOError):
        theirs.recv(1024)


NOT_QUIET = -1     # quiet_until: one second from now


@pytest.mark.parametrize("sent, quiet_until", [
    (mbap(1, UNIT, read_holding(0, 3)) + mbap(2, UNIT, read_holding(3, 3)), 0),
    (REQUEST[:9], 0),
    (mbap(TID, 0, read_holding(0, 3)), 0),
    (mbap(TID, 248, read_holding(0, 3)), 0),
    (mbap(TID, UNIT, bytes((0x6C, 0x01, 0x02))), 0),
    (mbap(TID, UNIT, bytes((0x08, 0x00, 0x00, 0x12, 0x34))), 0),
    (struct.pack(">HHHB", TID, 1, 6, UNIT) + read_holding(0, 3), 0),
    (struct.pack(">HHHB", TID, 0, 255, UNIT) + read_holding(0, 3), 0),
    (REQUEST, NOT_QUIET),
], ids=["two requests", "part of one", "unit 0", "unit 248", "FC 108", "FC 08",
        "protocol 1", "length 255", "line not yet quiet"])
def test_anything_else_is_left_whole_to_the_caller(line, socket_ends, sent, quiet_until):
    make, slave = line
    port = make()
    ours, theirs = socket_ends
    theirs.sendall(sent)
    if quiet_until == NOT_QUIET:
        quiet_until = time.monotonic_ns() + 1_000_000_000
    take = port.take_request(ours.fileno(), quiet_until)
    assert (take.status, take.taken) == (len(sent), False)
    assert take.input == sent
    assert nothing_written(slave)


def test_a_request_for_a_down_address_is_left_whole_to_the_caller(line, socket_ends):
    """The owner's table of down addresses is read as it is at each take: a request for an
    address marked down never reaches the line from C, and is taken once the mark is gone."""
    make, slave = line
    down = bytearray(256)
    port = make(down=down)
    ours, theirs = socket_ends
    down[UNIT] = 1
    theirs.sendall(REQUEST)
    take = port.take_request(ours.fileno(), 0)
    assert (take.status, take.taken, take.input) == (len(REQUEST), False, REQUEST)
    assert nothing_written(slave)
    down[UNIT] = 0
    got = slave_answers(slave, UNIT, holding_reply(0, 3))
    theirs.sendall(REQUEST)
    assert port.take_request(ours.fileno(), 0).taken
    assert got == [rtu(UNIT, read_holding(0, 3))]
    assert theirs.recv(1024) == mbap(TID, UNIT, holding_reply(0, 3))


def test_a_request_for_an_address_in_its_late_window_is_left_whole_to_the_caller(
        line, socket_ends):
    """The owner's late windows are read as they are at each take: a request for an address
    whose window has not ended never reaches the line from C (the late reply would look like
    its answer); once the window has ended (or is closed, 0) the request is taken."""
    make, slave = line
    late_until = array("q", bytes(8 * 256))
    port = make(late_until=late_until)
    ours, theirs = socket_ends
    late_until[UNIT] = time.monotonic_ns() + 60_000_000_000
    late_until[UNIT + 1] = 1        # another address's window does not hold this one
    theirs.sendall(REQUEST)
    take = port.take_request(ours.fileno(), 0)
    assert (take.status, take.taken, take.input) == (len(REQUEST), False, REQUEST)
    assert nothing_written(slave)
    late_until[UNIT] = time.monotonic_ns()      # ended
    got = slave_answers(slave, UNIT, holding_reply(0, 3))
    theirs.sendall(REQUEST)
    assert port.take_request(ours.fileno(), 0).taken
    assert got == [rtu(UNIT, read_holding(0, 3))]
    assert theirs.recv(1024) == mbap(TID, UNIT, holding_reply(0, 3))


def test_an_ended_connection_and_an_empty_one(line, socket_ends):
    make, _ = line
    port = make()
    ours, theirs = socket_ends
    assert port.take_request(ours.fileno(), 0)[1:3] == (-errno.EAGAIN, False)
    theirs.close()
    assert port.take_request(ours.fileno(), 0)[1:3] == (0, False)
