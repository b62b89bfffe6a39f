"""A remote line's one socket (mbgw.line.remote.RemoteLine) against loopback listeners: a
refused attempt starts the backoff (requests refused meanwhile without trying), logged once;
a connection the device closed is made again at once, counted a reconnect; the device back
is logged once."""
import logging
import socket
import time

import pytest

from mbgw.errors import TargetUnreachable
from mbgw.line import remote
from mbgw.line.remote import RemoteLine
from mbgw.ops.counters import RemoteCounters
from tests.harness import free_port


class Settings:
    stout_ms = 500


def line_to(port: int, kind: str = "modbus-tcp") -> RemoteLine:
    return RemoteLine("inverter", Settings(), kind, "127.0.0.1", port, 0, RemoteCounters())


def test_a_refused_attempt_backs_off_and_is_logged_once(caplog, monkeypatch):
    monkeypatch.setattr(remote, "BACKOFF_FIRST_S", 0.2)
    port = free_port()
    line = line_to(port)
    caplog.set_level(logging.INFO, "mbgw.line")
    with pytest.raises(TargetUnreachable):
        line.send(b"\x00")
    assert line.lost and line.holding
    with pytest.raises(TargetUnreachable, match="backing off"):
        line.send(b"\x00")                          # no attempt while the backoff holds
    with socket.create_server(("127.0.0.1", port)) as listener:
        while line.holding:
            time.sleep(0.01)
        line.send(b"\x01\x02")
        conn, _ = listener.accept()
        with conn:
            assert conn.recv(16) == b"\x01\x02"
        line.answered()
    assert not line.lost and line.counters.reconnects == 0
    logged = [r.getMessage() for r in caplog.records]
    assert sum("lost" in m for m in logged) == 1, logged
    assert sum("answers again" in m for m in logged) == 1, logged


def test_a_connection_the_device_closed_is_made_again_at_once():
    with socket.create_server(("127.0.0.1", 0)) as listener:
        line = line_to(listener.getsockname()[1])
        line.send(b"\x01")
        first, _ = listener.accept()
        first.close()                                # the device closes it
        assert line.receive(time.monotonic_ns() + 10**9) == b""   # seen as its end
        assert line.fd == -1
        line.send(b"\x02")                           # at once: no backoff
        second, _ = listener.accept()
        with second:
            assert second.recv(16) == b"\x02"
        assert (line.counters.reconnects, line.lost) == (1, False)
        line.close()


def test_over_udp_only_the_targets_datagrams_are_read():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as device, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
        device.bind(("127.0.0.1", 0))
        line = line_to(device.getsockname()[1], "modbus-udp")
        line.send(b"\x01")
        _, source = device.recvfrom(16)
        other.sendto(b"not the device", source)
        device.sendto(b"the device", source)
        assert bytes(line.receive(time.monotonic_ns() + 10**9)) == b"the device"
        line.close()
