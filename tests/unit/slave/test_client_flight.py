"""A client's requests in the gateway (mbgw.slave.connections.Client): written by admitted() and
answered(forwarded) only, in the C int the reply's forward counts down, and where the C
receive may send a reply (forward_target, a line.native.Forward)."""
import socket

import pytest

from mbgw.line.native import NO_FORWARD, Forward
from mbgw.slave.connections import MAX_IN_FLIGHT, Client


@pytest.fixture
def client():
    ours, theirs = socket.socketpair()
    yield Client(ours, "127.0.0.1", "127.0.0.1:1", "127.0.0.1:502")
    ours.close()
    theirs.close()


def test_admitted_and_answered_count_in_the_c_int(client):
    client.admitted()
    client.admitted()
    assert (client.in_flight, client.flight[0]) == (2, 2)
    client.answered()
    assert client.in_flight == 1


def test_a_reply_c_forwarded_was_counted_answered_by_c(client):
    client.admitted()
    client.flight[0] -= 1           # what csrc/forward.c does as it sends the reply
    client.answered(forwarded=12)
    assert client.in_flight == 0
    client.admitted()
    client.answered(forwarded=-1)   # none forwarded: answered here
    assert client.in_flight == 0


def test_a_full_client_is_not_readable_until_one_is_answered(client):
    for _ in range(MAX_IN_FLIGHT):
        client.admitted()
    assert not client.readable
    client.answered()
    assert client.readable


def test_the_forward_target_names_the_client_and_its_counter(client):
    target = client.forward_target(0x1234, 9, True)
    assert isinstance(target, Forward)
    assert target == Forward(client.fd, 0x1234, 9, True, client.flight)


def test_no_forward_once_a_reply_waits_or_the_client_closed(client):
    client._out += b"held"
    assert client.forward_target(1, 1, False) is NO_FORWARD
    client._out.clear()
    client.closed = True
    assert client.forward_target(1, 1, False) is NO_FORWARD
