"""Admission at the connection limit: which idle client a newcomer may take the place of
(mbgw.slave.server.eviction_victim), and what a connection tells the accepting thread about
itself (Client.probe, Client.busy), over real loopback TCP connections."""
import select
import socket
import struct
from types import SimpleNamespace

import pytest

from mbgw.config.model import ACTIVE_WINDOW_S
from mbgw.slave.connections import PEER_GONE, Client
from mbgw.slave.server import SLOW_REQUEST_S, eviction_victim
from tests.modbus import mbap, read_holding
from tests.wait import until

NOW = 1000.0


def idle(name: str, requests: int, quiet_s: float, partial_s: float = 0.0) -> SimpleNamespace:
    """An idle client's figures, as eviction_victim reads them; partial_s: how long a request
    it has begun has been waiting for its other bytes."""
    return SimpleNamespace(name=name, requests=requests, last_active=NOW - quiet_s,
                           partial_since=NOW - partial_s if partial_s else 0.0,
                           busy=bool(partial_s))


def victim(*clients) -> str | None:
    chosen = eviction_victim(list(clients), NOW)
    return chosen.name if chosen else None


def test_one_that_never_sent_a_request_goes_first_even_before_a_long_quiet_one():
    assert victim(idle("quiet", 5, 10 * ACTIVE_WINDOW_S), idle("silent", 0, 0.1)) == "silent"


def test_of_those_that_never_sent_a_request_the_least_recently_active_goes():
    assert victim(idle("new", 0, 0.1), idle("older", 0, 2.0), idle("poller", 9, 0)) == "older"


def test_one_dribbling_its_first_request_goes_first_even_while_active():
    assert victim(idle("quiet", 5, 10 * ACTIVE_WINDOW_S),
                  idle("dribbler", 0, 0.0, partial_s=0.1)) == "dribbler"


def test_a_poller_slow_with_a_request_goes_before_a_quiet_one():
    assert victim(idle("quiet", 5, 10 * ACTIVE_WINDOW_S),
                  idle("slow", 5, 0.0, partial_s=SLOW_REQUEST_S)) == "slow"


def test_a_poller_whose_request_is_under_way_is_never_chosen():
    assert victim(idle("sending", 5, ACTIVE_WINDOW_S + 1, partial_s=0.01)) is None


def test_a_client_active_within_the_window_is_never_chosen():
    assert victim(idle("a", 3, 0.0), idle("b", 3, ACTIVE_WINDOW_S - 1)) is None


def test_of_the_quiet_ones_the_least_recently_active_goes():
    assert victim(idle("poller", 3, 1.0), idle("quiet", 3, ACTIVE_WINDOW_S),
                  idle("quieter", 3, ACTIVE_WINDOW_S + 5)) == "quieter"


def test_nobody_idle_nobody_chosen():
    assert victim() is None


@pytest.fixture
def tcp():
    """connect() -> (Client on the gateway's end of a loopback TCP connection, the peer's
    socket); everything closed after the test."""
    listener = socket.create_server(("127.0.0.1", 0))
    opened = []

    def connect() -> tuple[Client, socket.socket]:
        peer = socket.create_connection(listener.getsockname())
        ours, address = listener.accept()
        ours.setblocking(False)
        client = Client(ours, address[0], "peer", "local")
        opened.append((client, peer))
        return client, peer

    yield connect
    for client, peer in opened:
        client.close()
        peer.close()
    listener.close()


def shows(client: Client, events: int) -> bool:
    """Whether the probe shows events within a second (loopback delivers at once, mostly)."""
    return bool(until(lambda: client.probe() & events, f"the events {events:#x} shown", 1.0))


def test_a_quiet_live_connection_shows_nothing(tcp):
    client, _ = tcp()
    assert client.probe() == 0 and not client.busy


def test_input_not_read_yet_shows(tcp):
    client, peer = tcp()
    peer.sendall(mbap(1, 1, read_holding(0, 1)))
    assert shows(client, select.POLLIN) and not client.probe() & PEER_GONE


def test_a_peer_that_closed_is_gone_even_with_input_unread(tcp):
    client, peer = tcp()
    peer.sendall(mbap(1, 1, read_holding(0, 1))[:3])
    peer.close()
    assert shows(client, PEER_GONE)


def test_a_peer_that_reset_is_gone(tcp):
    client, peer = tcp()
    peer.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    peer.close()
    assert shows(client, PEER_GONE)


def test_a_connection_the_line_thread_closed_is_gone(tcp):
    client, _ = tcp()
    client.close()
    assert shows(client, PEER_GONE)


def test_part_of_a_request_read_makes_a_client_busy(tcp):
    client, _ = tcp()
    assert client.received(mbap(1, 1, read_holding(0, 1))[:5], 0) == []
    assert client.busy
