"""The serial device disappears while the gateway runs, and comes back.

The device is a socat pty pair (tests/harness.py PtyPair) with pymodbus 3.16.1's RTU server on
its far end (tests/peers/pymodbus_slave.py, slave 17: holding register n holds 100 + n).
Stopping socat removes the pty under the gateway, as unplugging a USB adapter does; starting it
again with the same link names brings the device back at the same path.
"""
import socket
import struct
import time

import pytest

from tests.modbus import mbap as adu

pytestmark = pytest.mark.integration

STOUT_S = 1.0
PROMPT_S = 0.3            # "promptly": well before stout
RECOVERY_S = 8.0          # the gateway retries the device with backoff (0.5 s, then doubling)


def recv_adu(sock: socket.socket, timeout: float) -> bytes:
    deadline = time.monotonic() + timeout
    data = b""
    need = 6
    while len(data) < need:
        sock.settimeout(max(deadline - time.monotonic(), 0.001))
        chunk = sock.recv(need - len(data))
        if not chunk:
            raise ConnectionError(f"EOF after {data.hex(' ')!r}")
        data += chunk
        if len(data) == 6:
            need = 6 + struct.unpack(">H", data[4:6])[0]
    return data


READ_3 = bytes.fromhex("03 0000 0003")
REPLY_3 = bytes.fromhex("03 06 0064 0065 0066")     # 100, 101, 102
PATH_UNAVAILABLE = bytes.fromhex("83 0a")


def timed_transact(sock: socket.socket, tid: int, timeout: float) -> tuple[bytes, float]:
    start = time.monotonic()
    sock.sendall(adu(tid, 17, READ_3))
    reply = recv_adu(sock, timeout)
    assert reply[:4] == struct.pack(">HH", tid, 0) and reply[6] == 17, reply.hex(" ")
    return reply[7:], time.monotonic() - start


def test_device_loss_answers_0x0a_then_recovers_without_restart(pty_pair, start_peer,
                                                                start_gateway):
    start_peer("pymodbus_slave.py", pty_pair.device)
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--exception",
                       "--stout", str(int(STOUT_S * 1000)))
    pid = gw.proc.pid
    with socket.create_connection(("127.0.0.1", gw.port)) as sock:
        assert timed_transact(sock, 1, STOUT_S + 2)[0] == REPLY_3

        pty_pair.stop()                       # the device disappears (socat has exited)
        for tid in range(2, 6):
            reply, took = timed_transact(sock, tid, STOUT_S + 2)
            assert reply == PATH_UNAVAILABLE, reply.hex(" ")
            assert took < PROMPT_S, f"0x0A took {took:.3f} s (stout {STOUT_S} s)"

        pty_pair.start()                      # the device comes back at the same path
        start_peer("pymodbus_slave.py", pty_pair.device)
        # Poll for recovery against a deadline: until the gateway has reopened the device it
        # answers 0x0A at once (0x0B if it reopened before the peer listened).
        deadline = time.monotonic() + RECOVERY_S
        tid, replies = 100, []
        while True:
            reply, _ = timed_transact(sock, tid, STOUT_S + 2)
            replies.append(reply)
            if reply == REPLY_3:
                break
            assert reply in (PATH_UNAVAILABLE, bytes.fromhex("83 0b")), replies
            assert time.monotonic() < deadline, f"not served again after {RECOVERY_S} s"
            tid += 1
            time.sleep(0.05)                  # poll interval, not synchronisation
        assert timed_transact(sock, 1000, STOUT_S + 2)[0] == REPLY_3

    assert gw.proc.poll() is None and gw.proc.pid == pid, "the gateway was restarted or died"
    lines = gw.log().splitlines()
    lost = [line for line in lines if "lost" in line]
    back = [line for line in lines if "is back" in line]
    assert len(lost) == 1 and pty_pair.gateway in lost[0], lines
    assert len(back) == 1 and pty_pair.gateway in back[0], lines
    assert lines.index(lost[0]) < lines.index(back[0])


def test_device_loss_without_exception_leaves_clients_unanswered_but_connected(
        pty_pair, start_peer, start_gateway):
    start_peer("pymodbus_slave.py", pty_pair.device)
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--stout", "1000")
    with socket.create_connection(("127.0.0.1", gw.port)) as sock:
        assert timed_transact(sock, 1, STOUT_S + 2)[0] == REPLY_3
        pty_pair.stop()
        sock.sendall(adu(2, 17, READ_3))
        with pytest.raises(socket.timeout):   # no answer at all, and no EOF
            recv_adu(sock, 0.5)
        pty_pair.start()
        start_peer("pymodbus_slave.py", pty_pair.device)
        # Poll for recovery against a deadline.  A request sent before the peer listened may
        # still be answered late (socat kept its bytes), so any request sent may be the one.
        deadline = time.monotonic() + RECOVERY_S
        sent = []
        while True:
            sent.append(100 + len(sent))
            sock.sendall(adu(sent[-1], 17, READ_3))
            try:
                reply = recv_adu(sock, 0.5)
            except socket.timeout:
                assert time.monotonic() < deadline, f"not served again after {RECOVERY_S} s"
                continue
            assert reply[7:] == REPLY_3 and struct.unpack(">H", reply[:2])[0] in sent, \
                reply.hex(" ")
            break
    assert gw.proc.poll() is None
