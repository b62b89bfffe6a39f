"""The serial device disappears while the gateway runs, and comes back.

The device is a socat pty pair (tests/harness.py PtyPair) with pymodbus 3.16.1's RTU server on
its far end (tests/peers/pymodbus_slave.py, slave 17: holding register n holds 100 + n).
Stopping socat removes the pty under the gateway, as unplugging a USB adapter does; starting it
again with the same link names brings the device back at the same path.  A regular file put
at that path stands for a device that is there but cannot be opened as a serial line; the
kernel (inotify) counts the gateway's attempts to open it.
"""
import ctypes
import os
import select
import socket
import struct
import time

import pytest

from tests.modbus import mbap as adu
from tests.modbus import recv_adu
from tests.ops import wait_for_log

pytestmark = [pytest.mark.integration, pytest.mark.serial]

STOUT_S = 1.0
PROMPT_S = 0.3            # "promptly": well before stout
RECOVERY_S = 8.0          # the gateway retries the device with backoff (0.5 s, then doubling)
OUTAGE_S = 4.0            # long enough for a backoff from 0.5 s to reach its 2 s and 4 s steps
BACK_WITHIN_S = 1.0       # served again this soon after the device is back (the rule: 0.5 s)
WATCH_S = 4.0             # how long the attempts to open a device that fails are counted
# Backing off from 0.5 s, the attempts after the first are 0.5, 1.5 and 3.5 s after it: at most
# 3 in WATCH_S.  Retrying every 0.5 s would make 8, spinning thousands.
ATTEMPTS_MAX = 5


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


def refused_for(sock: socket.socket, seconds: float, tid: int) -> int:
    """Ask for `seconds` while the device is down: each request is refused at once (0x0A).
    Returns the next transaction id."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        reply, took = timed_transact(sock, tid, STOUT_S + 2)
        assert reply == PATH_UNAVAILABLE, reply.hex(" ")
        assert took < PROMPT_S, f"0x0A took {took:.3f} s (stout {STOUT_S} s)"
        tid += 1
        time.sleep(0.1)                       # the clients' pace, not synchronisation
    return tid


def served_after(sock: socket.socket, tid: int) -> float:
    """Ask until a request is served (against RECOVERY_S); how long that took."""
    start = time.monotonic()
    while True:
        reply, _ = timed_transact(sock, tid, STOUT_S + 2)
        took = time.monotonic() - start
        if reply == REPLY_3:
            return took
        assert reply == PATH_UNAVAILABLE, reply.hex(" ")
        assert took < RECOVERY_S, f"not served again after {RECOVERY_S} s"
        tid += 1
        time.sleep(0.02)                      # poll interval, not synchronisation


def bring_back(pty_pair, start_peer) -> None:
    """The device is back at its path (socat's links exist) and its slave is READY."""
    pty_pair.start()
    start_peer("pymodbus_slave.py", pty_pair.device)


def serving(pty_pair, start_peer, start_gateway):
    """A gateway with --exception whose device has just served, and a client of it."""
    start_peer("pymodbus_slave.py", pty_pair.device)
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--exception",
                       "--stout", str(int(STOUT_S * 1000)))
    sock = socket.create_connection(("127.0.0.1", gw.port))
    assert timed_transact(sock, 1, STOUT_S + 2)[0] == REPLY_3
    return gw, sock


def test_device_back_after_a_long_outage_is_served_within_a_second(pty_pair, start_peer,
                                                                   start_gateway):
    gw, sock = serving(pty_pair, start_peer, start_gateway)
    with sock:
        pty_pair.stop()
        tid = refused_for(sock, OUTAGE_S, 2)
        bring_back(pty_pair, start_peer)
        took = served_after(sock, tid)
        assert took < BACK_WITHIN_S, f"served {took:.2f} s after the device came back"
    # an absent device is only looked at: no open attempt to fail, nothing logged
    lines = gw.log().splitlines()
    assert not [line for line in lines if " WARNING " in line], lines
    assert [line for line in lines if " ERROR " in line] == \
        [line for line in lines if "lost" in line], lines


class OpenAttempts:
    """The attempts to open one file, whoever makes them (inotify): an attempt is the opens
    between two closes (mbgw's lock opens the device, then libmodbus does).  The kernel merges
    an event into the same unread event before it, so the opens alone could not be counted."""
    IN_OPEN = 0x20
    IN_CLOSE = 0x08 | 0x10                    # IN_CLOSE_WRITE | IN_CLOSE_NOWRITE
    EVENT = struct.Struct("iIII")             # struct inotify_event without its name

    def __init__(self, path: str) -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        self.fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        if self.fd < 0 or libc.inotify_add_watch(self.fd, path.encode(),
                                                  self.IN_OPEN | self.IN_CLOSE) < 0:
            raise OSError(ctypes.get_errno(), f"inotify on {path}")

    def count(self) -> int:
        attempts, opened = 0, False
        while select.select([self.fd], [], [], 0)[0]:
            events = os.read(self.fd, 4096)
            offset = 0
            while offset < len(events):
                _, mask, _, name_len = self.EVENT.unpack_from(events, offset)
                offset += self.EVENT.size + name_len
                attempts += bool(mask & self.IN_OPEN and not opened)
                opened = bool(mask & self.IN_OPEN)
        return attempts

    def close(self) -> None:
        os.close(self.fd)


def test_a_device_that_cannot_be_opened_is_logged_once_and_backed_off(pty_pair, start_peer,
                                                                      start_gateway):
    gw, sock = serving(pty_pair, start_peer, start_gateway)
    with sock:
        pty_pair.stop()
        wait_for_log(gw, "lost")
        with open(pty_pair.gateway, "w"):     # there, but no tty: every open fails (ENOTTY)
            pass
        wait_for_log(gw, f"cannot open {pty_pair.gateway}")
        attempts = OpenAttempts(pty_pair.gateway)
        try:
            tid = refused_for(sock, WATCH_S, 2)    # the daemon stays responsive meanwhile
            tried = attempts.count()
        finally:
            attempts.close()
        assert 1 <= tried <= ATTEMPTS_MAX, f"{tried} attempts to open in {WATCH_S} s"

        os.unlink(pty_pair.gateway)           # the real device again, in the middle of a backoff
        bring_back(pty_pair, start_peer)
        took = served_after(sock, tid)
        assert took < BACK_WITHIN_S, f"served {took:.2f} s after the device came back"

    lines = gw.log().splitlines()
    failed = [line for line in lines if "cannot open" in line]
    assert len(failed) == 1 and " WARNING " in failed[0] and "backoff" in failed[0], lines
    assert len([line for line in lines if "is back" in line]) == 1, lines
