"""The Modbus/UDP listener's datagrams (mbgw.slave.udp_face), over real loopback sockets:
who is served, who gets nothing, and what a retransmission costs."""
import ipaddress
import select
import socket

import pytest

from mbgw.config.firewall import FirewallConfig, Rule
from mbgw.firewall.guard import Firewall
from mbgw.line import native
from mbgw.net.acl import AccessList
from mbgw.ops.counters import FaceCounters
from mbgw.slave.udp_face import UdpPort
from tests.harness import factory
from tests.modbus import mbap, read_holding

STOUT_MS = 1000
REPLY = bytes.fromhex("03 02 0064")


class Rig:
    def __init__(self, authip=(), firewall: Firewall | None = None) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        self.face = FaceCounters()
        self.requests: list = []
        self.port = UdpPort(sock, self.on_request, AccessList(authip),
                            firewall or Firewall(None), self.face, STOUT_MS)
        self.client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.client.bind(("127.0.0.1", 0))
        self.client.settimeout(0.2)

    def on_request(self, peer, tid, unit, pdu) -> None:
        peer.admitted()
        self.requests.append((peer, tid, unit, pdu))

    def send(self, datagram: bytes) -> None:
        """datagram to the port, then the port's turn once it is there."""
        self.client.sendto(datagram, self.port.sock.getsockname())
        assert select.select([self.port.sock], [], [], 1.0)[0]
        self.port.ready()

    def answer(self, index: int = -1) -> None:
        peer, tid, unit, _ = self.requests[index]
        peer.answered()
        peer.send(native.frame(tid, unit, REPLY))

    def close(self) -> None:
        self.port.close()
        self.client.close()


@pytest.fixture
def rig():
    yield from factory(Rig, Rig.close)


def test_a_request_reaches_the_router_and_its_reply_leaves_from_the_port(rig):
    r = rig()
    r.send(mbap(5, 17, read_holding(0, 1)))
    [(peer, tid, unit, pdu)] = r.requests
    assert (tid, unit, pdu, peer.listener) == (5, 17, read_holding(0, 1), "udp")
    r.answer()
    data, source = r.client.recvfrom(512)
    assert data == native.frame(5, 17, REPLY) and source == r.port.sock.getsockname()
    assert r.port.sources == 1


def test_a_retransmission_is_answered_from_memory_or_not_at_all_while_outstanding(rig):
    r = rig()
    datagram = mbap(5, 17, read_holding(0, 1))
    r.send(datagram)
    r.send(datagram)                        # outstanding: nothing
    with pytest.raises(TimeoutError):
        r.client.recvfrom(512)
    r.answer()
    assert r.client.recvfrom(512)[0] == native.frame(5, 17, REPLY)
    r.send(datagram)                        # answered: the same reply again
    assert r.client.recvfrom(512)[0] == native.frame(5, 17, REPLY)
    assert len(r.requests) == 1 and r.face.retransmissions == 2
    r.send(mbap(5, 17, read_holding(1, 1)))     # the same tid, other bytes: a new request
    assert len(r.requests) == 2


def test_authip_and_the_firewall_refuse_without_a_datagram(rig):
    refused = rig(authip=(ipaddress.ip_address("10.1.2.3"),))
    refused.send(mbap(1, 17, read_holding(0, 1)))
    unit_1_only = FirewallConfig(rules=(Rule(1, listener="udp", units=(1,)),))
    guarded = rig(firewall=Firewall(unit_1_only))
    guarded.send(mbap(1, 17, read_holding(0, 1)))
    for r in (refused, guarded):
        with pytest.raises(TimeoutError):
            r.client.recvfrom(512)
        assert r.requests == [] and r.face.refused == 1
    assert (refused.port.sources, guarded.port.sources) == (0, 1)
    assert guarded.port.peers and guarded.port.peers.popitem()[1].firewall_refused == 1


def test_a_datagram_that_is_no_mbap_frame_is_dropped_and_counted(rig):
    r = rig()
    r.send(mbap(1, 17, read_holding(0, 1))[:-1])     # shorter than its length says
    assert r.requests == [] and r.face.bad_frames == 1
