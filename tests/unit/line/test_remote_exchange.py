"""A remote line's Modbus TCP exchange in C (csrc/remote.c through native.MbapExchange),
against a device played on the other end of a socketpair: the request on the wire, the reply
however the stream cuts it, whatever else came dropped and counted.  Then the same through
the line's socket and framing (RemoteLine.exchange, MbapFraming.exchange) against a loopback
listener: the counters, a connection out of step dropped, one closed by the device made
again."""
import errno
import select
import socket
import struct
import threading
import time
from collections.abc import Callable

import pytest

from mbgw.errors import LineTimeout
from mbgw.line.native import MbapExchange
from mbgw.line.remote import RemoteLine
from mbgw.ops.counters import RemoteCounters
from mbgw.slave.remote_framing import remote_framing
from tests.wait import until

READ = bytes.fromhex("01 03 00 00 00 02")        # unit 1, FC 03, 2 registers from 0
REPLY_PDU = bytes.fromhex("03 04 00 0a 00 0b")
STOUT_NS = 2 * 10**9


def mbap(tid: int, unit: int, pdu: bytes, protocol: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1, unit) + pdu


Device = Callable[[socket.socket, bytes], None]     # answers the request it read


def exchange(device: Device, adu: bytes = READ, tid: int = 7, stout_ns: int = STOUT_NS,
             before: bytes = b""):
    """One exchange through a socketpair whose other end device plays (before: what waits
    unread when the request goes); returns (result code, MbapExchange, the request read)."""
    ours, theirs = socket.socketpair()
    ex = MbapExchange()
    seen: list[bytes] = []

    def play() -> None:
        request = theirs.recv(300)
        seen.append(request)
        device(theirs, request)

    with ours, theirs:
        ours.setblocking(False)
        if before:
            theirs.sendall(before)
        peer = threading.Thread(target=play)
        peer.start()
        n = ex.exchange(ours.fileno(), adu, tid, stout_ns)
        peer.join()
    return n, ex, seen[0] if seen else b""


def reply_to(tid: int) -> bytes:
    return mbap(tid, 1, REPLY_PDU)


def test_the_request_goes_in_one_mbap_frame_with_our_tid_and_the_reply_comes_back():
    n, ex, request = exchange(lambda dev, req: dev.sendall(reply_to(7)), tid=7)
    assert request == mbap(7, 1, READ[1:])
    assert n == len(reply_to(7))
    assert ex.reply(n) == b"\x01" + REPLY_PDU
    r = ex.result
    assert (r.strays, r.noise, r.left, r.stale, r.received) == (0, 0, 0, 0, n)
    assert 0 < r.sent_ns <= r.end_ns


def test_a_reply_in_one_byte_pieces_is_put_together():
    def piecemeal(dev: socket.socket, req: bytes) -> None:
        for byte in reply_to(7):
            dev.send(bytes([byte]))
            time.sleep(0.002)       # pacing, so that the pieces arrive apart
    n, ex, _ = exchange(piecemeal)
    assert ex.reply(n) == b"\x01" + REPLY_PDU
    assert ex.result.strays == 0


def test_a_stray_tid_before_the_reply_in_the_same_segment_is_dropped_and_counted():
    n, ex, _ = exchange(lambda dev, req: dev.sendall(reply_to(6) + reply_to(7)))
    assert n > 0 and ex.reply(n) == b"\x01" + REPLY_PDU
    assert ex.result.strays == 1


def test_what_follows_the_reply_in_its_segment_is_left_and_dropped():
    n, ex, _ = exchange(lambda dev, req: dev.sendall(reply_to(7) + reply_to(8)))
    assert ex.reply(n) == b"\x01" + REPLY_PDU
    assert ex.result.left == len(reply_to(8))


@pytest.mark.parametrize("stray", [
    mbap(7, 2, REPLY_PDU),                              # another unit
    mbap(7, 1, bytes.fromhex("04 04 00 0a 00 0b")),     # another function
    mbap(7, 1, bytes.fromhex("03 02 00 0a")),           # a size not asked for
    mbap(7, 1, bytes.fromhex("83 02 00")),              # an exception too long
], ids=["unit", "function", "size", "exception-length"])
def test_a_frame_with_our_tid_that_does_not_answer_is_a_stray(stray):
    n, ex, _ = exchange(lambda dev, req: dev.sendall(stray + reply_to(7)))
    assert ex.reply(n) == b"\x01" + REPLY_PDU
    assert ex.result.strays == 1


def test_an_exception_answers():
    n, ex, _ = exchange(lambda dev, req: dev.sendall(mbap(7, 1, b"\x83\x02")))
    assert ex.reply(n) == b"\x01\x83\x02"


def test_protocol_id_1_puts_the_stream_out_of_step():
    bad = mbap(7, 1, REPLY_PDU, protocol=1)
    n, ex, _ = exchange(lambda dev, req: dev.sendall(bad))
    assert n == -errno.EPROTO
    assert ex.result.noise == len(bad)


def test_no_reply_times_out_at_stout():
    n, ex, _ = exchange(lambda dev, req: None, stout_ns=50_000_000)
    assert n == -errno.ETIMEDOUT
    r = ex.result
    assert r.end_ns - r.sent_ns >= 50_000_000


def test_half_a_frame_by_stout_is_no_reply():
    n, ex, _ = exchange(lambda dev, req: dev.sendall(reply_to(7)[:-1]), stout_ns=50_000_000)
    assert n == -errno.ETIMEDOUT
    assert ex.result.received == len(reply_to(7)) - 1


def test_what_waited_before_the_request_is_dropped_unread():
    late = reply_to(7)          # a late reply that looks like the answer
    n, ex, _ = exchange(lambda dev, req: dev.sendall(reply_to(8)), tid=8, before=late)
    assert ex.reply(n) == b"\x01" + REPLY_PDU
    assert ex.result.stale == len(late) and ex.result.strays == 0


def test_a_device_that_closes_instead_of_answering_ends_the_exchange():
    n, ex, _ = exchange(lambda dev, req: dev.shutdown(socket.SHUT_WR))
    assert n == -errno.ENOTCONN
    assert ex.result.sent_ns > 0


def test_what_waited_before_a_close_is_counted_and_the_request_not_sent():
    ours, theirs = socket.socketpair()
    with ours, theirs:
        ours.setblocking(False)
        theirs.sendall(reply_to(3))
        theirs.shutdown(socket.SHUT_WR)
        ex = MbapExchange()
        n = ex.exchange(ours.fileno(), READ, 4, STOUT_NS)
        ours.close()
        assert theirs.recv(300) == b""          # nothing was sent before the end
    assert n == -errno.ENOTCONN
    assert (ex.result.sent_ns, ex.result.stale) == (0, len(reply_to(3)))


def test_a_connection_closed_before_the_request_is_not_sent_on():
    ours, theirs = socket.socketpair()
    with ours:
        ours.setblocking(False)
        theirs.close()
        ex = MbapExchange()
        n = ex.exchange(ours.fileno(), READ, 1, STOUT_NS)
    assert n in (-errno.ENOTCONN, -errno.EPIPE, -errno.ECONNRESET)
    assert ex.result.sent_ns == 0


# --- through the remote line's socket and framing (RemoteLine.exchange, MbapFraming) ---

class Settings:
    stout_ms = 500


def framed_line(port: int):
    line = RemoteLine("inverter", Settings(), "modbus-tcp", "127.0.0.1", port, 0,
                      RemoteCounters())
    return line, remote_framing(line)


def test_the_framing_counts_what_c_dropped_and_takes_the_reply():
    with socket.create_server(("127.0.0.1", 0)) as listener:
        line, framing = framed_line(listener.getsockname()[1])
        assert framing.exchanges(READ)
        done = threading.Event()

        def device() -> None:
            conn, _ = listener.accept()
            with conn:
                tid = struct.unpack(">H", conn.recv(300)[:2])[0]
                conn.sendall(reply_to(tid - 1) + reply_to(tid) + reply_to(tid)[:3])
                done.wait(5)

        peer = threading.Thread(target=device)
        peer.start()
        got = framing.exchange(READ, STOUT_NS)
        done.set()
        peer.join()
        line.close()
    assert got.frame == b"\x01" + REPLY_PDU and got.fault is None
    assert got.last_byte_ns >= got.request_end_ns > 0
    counters = line.counters
    assert counters.stray_replies == 2      # the tid before, what followed the reply
    assert counters.bytes_sent == len(mbap(1, 1, READ[1:]))
    assert counters.bytes_received == 3 * len(reply_to(1)) - (len(reply_to(1)) - 3)


def test_a_header_out_of_step_drops_the_connection_and_is_no_reply():
    with socket.create_server(("127.0.0.1", 0)) as listener:
        line, framing = framed_line(listener.getsockname()[1])

        def device() -> None:
            conn, _ = listener.accept()
            with conn:
                conn.recv(300)
                conn.sendall(mbap(1, 1, REPLY_PDU, protocol=1))
                conn.recv(1)            # until the gateway closes it

        peer = threading.Thread(target=device)
        peer.start()
        got = framing.exchange(READ, STOUT_NS)
        peer.join()
    assert isinstance(got.fault, LineTimeout) and got.frame is None
    assert line.fd == -1
    assert (line.counters.stray_replies, line.counters.noise_bytes) == \
        (1, len(mbap(1, 1, REPLY_PDU)))


def test_a_request_the_closed_connection_did_not_take_goes_on_a_new_one():
    with socket.create_server(("127.0.0.1", 0)) as listener:
        line, framing = framed_line(listener.getsockname()[1])
        line.send(b"")                          # the first connection, made
        first, _ = listener.accept()
        first.close()                           # the device closes it, unseen
        until(lambda: select.select([line.fd], [], [], 0)[0], "the close arrived", 5)

        def device() -> None:
            conn, _ = listener.accept()
            with conn:
                tid = struct.unpack(">H", conn.recv(300)[:2])[0]
                conn.sendall(reply_to(tid))

        peer = threading.Thread(target=device)
        peer.start()
        got = framing.exchange(READ, STOUT_NS)
        peer.join()
        line.close()
    assert got.frame == b"\x01" + REPLY_PDU
    assert line.counters.reconnects == 1
