"""A lent client's request taken to a remote Modbus TCP line in C (csrc/remote.c
mbgw_remote_take and mbgw_remote_reply through native.MbapExchange), with both the client
and the device played on the other ends of socketpairs: only exactly one whole request for
the line is taken, anything else is left in the client's socket unread; a taken request goes
to the device under our transaction id and its address on the line, and the reply to the
client under the client's own transaction id and unit, counted out of the client's flight."""
import errno
import socket
import struct

import pytest

from mbgw.line.native import Forward, MbapExchange, counter

# Modbus Application Protocol V1.1b3, 6.3: read holding registers 108-110 (0x006B, 3 regs)
READ_PDU = bytes.fromhex("03 006B 0003")
REPLY_PDU = bytes.fromhex("03 06 022B 0000 0064")     # ... and its reply: 555, 0, 100
STOUT_NS = 2 * 10**9
UNIT = 40               # the client's unit, the line's address 1 (a route's address = 1)


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


@pytest.fixture
def ends():
    """(client side: the client's end, ours), (line side: ours, the device's end)."""
    client, ours_c = socket.socketpair()
    ours_l, device = socket.socketpair()
    for s in (ours_c, ours_l):
        s.setblocking(False)
    device.settimeout(2)
    client.settimeout(2)
    yield (client, ours_c), (ours_l, device)
    for s in (client, ours_c, ours_l, device):
        s.close()


def lent(units: dict[int, int] | None = None, down: tuple[int, ...] = ()):
    ex = MbapExchange()
    table = bytearray(256)
    for unit, address in (units or {UNIT: 1}).items():
        table[unit] = address
    flags = bytearray(256)
    for address in down:
        flags[address] = 1
    ex.lend_rules(table, flags)
    return ex, table, flags


def unread(sock: socket.socket) -> bytes:
    """What waits in sock, left there."""
    timeout = sock.gettimeout()
    sock.setblocking(False)
    try:
        return sock.recv(1000, socket.MSG_PEEK)
    except BlockingIOError:
        return b""
    finally:
        sock.settimeout(timeout)


def test_one_request_for_the_line_goes_out_and_its_reply_comes_back_under_the_clients_ids(
        ends):
    (client, ours_c), (ours_l, device) = ends
    ex, *_ = lent()
    flight = counter()
    client.sendall(mbap(0x1234, UNIT, READ_PDU))
    assert ex.take(ours_c.fileno(), flight, ours_l.fileno(), 7) == 1
    assert ex.loan.send_error == 0 and flight[0] == 1
    assert device.recv(300) == mbap(7, 1, READ_PDU)           # our tid, its address
    assert (ex.loan.tid, ex.loan.unit, ex.taken_adu()) == (0x1234, UNIT, b"\x01" + READ_PDU)
    device.sendall(mbap(7, 1, REPLY_PDU))
    to = Forward(ours_c.fileno(), ex.loan.tid, ex.loan.unit, False, flight)
    n = ex.reply_to_loan(ours_l.fileno(), 7, ex.result.sent_ns + STOUT_NS, to)
    assert n == len(mbap(7, 1, REPLY_PDU))
    assert client.recv(300) == mbap(0x1234, UNIT, REPLY_PDU)  # the client's tid and unit
    assert (ex.result.forwarded, flight[0]) == (n, 0)
    assert ex.reply(n) == b"\x01" + REPLY_PDU               # left as it came, for the books


@pytest.mark.parametrize("sent", [
    mbap(1, UNIT, READ_PDU) + mbap(2, UNIT, READ_PDU),      # two requests
    mbap(1, UNIT, READ_PDU)[:9],                            # part of one
    mbap(1, UNIT + 1, READ_PDU),                            # a unit not the line's
    struct.pack(">HHHB", 1, 1, 6, UNIT) + READ_PDU,         # protocol id 1: not Modbus
])
def test_anything_but_one_request_for_the_line_stays_unread(ends, sent):
    (client, ours_c), (ours_l, device) = ends
    ex, *_ = lent()
    flight = counter()
    client.sendall(sent)
    assert ex.take(ours_c.fileno(), flight, ours_l.fileno(), 7) == 0
    assert unread(ours_c) == sent and flight[0] == 0
    assert unread(device) == b""


def test_a_request_to_an_address_that_is_down_stays_unread(ends):
    (client, ours_c), (ours_l, device) = ends
    ex, table, flags = lent(down=(1,))
    client.sendall(mbap(1, UNIT, READ_PDU))
    assert ex.take(ours_c.fileno(), counter(), ours_l.fileno(), 7) == 0
    flags[1] = 0                        # the rules are read in place, at every take
    assert ex.take(ours_c.fileno(), counter(), ours_l.fileno(), 7) == 1
    assert device.recv(300) == mbap(7, 1, READ_PDU)


def test_nothing_waiting_is_eagain_and_the_end_is_no_take(ends):
    (client, ours_c), (ours_l, _) = ends
    ex, *_ = lent()
    assert ex.take(ours_c.fileno(), counter(), ours_l.fileno(), 7) == -errno.EAGAIN
    client.shutdown(socket.SHUT_WR)
    assert ex.take(ours_c.fileno(), counter(), ours_l.fileno(), 7) == 0


def test_a_line_the_device_closed_takes_the_request_unsent(ends):
    (client, ours_c), (ours_l, device) = ends
    ex, *_ = lent()
    device.close()
    client.sendall(mbap(1, UNIT, READ_PDU))
    assert ex.take(ours_c.fileno(), counter(), ours_l.fileno(), 7) == 1
    assert ex.loan.send_error < 0 and ex.result.sent_ns == 0
    assert ex.taken_adu() == b"\x01" + READ_PDU              # for the exchange that follows


def test_a_reply_to_another_transaction_is_never_forwarded(ends):
    (client, ours_c), (ours_l, device) = ends
    ex, *_ = lent()
    flight = counter()
    client.sendall(mbap(9, UNIT, READ_PDU))
    assert ex.take(ours_c.fileno(), flight, ours_l.fileno(), 7) == 1
    device.recv(300)
    device.sendall(mbap(6, 1, REPLY_PDU))                     # a late one's tid
    to = Forward(ours_c.fileno(), 9, UNIT, False, flight)
    n = ex.reply_to_loan(ours_l.fileno(), 7, ex.result.sent_ns + 50_000_000, to)
    assert n == -errno.ETIMEDOUT and ex.result.strays == 1
    assert (ex.result.forwarded, flight[0]) == (-1, 1)
    assert unread(client) == b""
