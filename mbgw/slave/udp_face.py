"""The Modbus TCP face's Modbus/UDP listener (`[net] udp-port`): its datagrams read on the
face's home thread (line serial's, or `mbgw-tcp-face`), each source a client of its own
(`UdpPeer`) to the router, with the face's routes, its fairness and the firewall.

authip and the firewall are checked per datagram before anything is sent: a source they
refuse gets no datagram at all, not even 0x01, so a forged source address draws nothing (a
12-byte request can ask for a 259-byte reply).  A retransmission (the same source, transaction
id and bytes within stout of the first) never reaches the target again: it gets the first
reply again, or nothing while that one is outstanding.  Replies leave from the socket the
request came in on (the udp-port).
"""
import socket
import time

from mbgw.firewall.guard import Firewall
from mbgw.line.native import HEADER, HEADER_LEN, NO_FORWARD, Forward, frame_length
from mbgw.net.acl import AccessList
from mbgw.net.address import format_address
from mbgw.ops.counters import FaceCounters
from mbgw.slave.connections import Client

DATAGRAM_SIZE = 512          # an MBAP frame is 260 bytes at most: more is no request
DATAGRAMS_PER_TURN = 64      # read in one wake-up at most, so TCP clients are read between
MAX_PEERS = 1024             # sources remembered; beyond, the idle ones are forgotten
MAX_REMEMBERED = 64          # requests a source has answered from memory; beyond, the old go
_NEW = object()              # a source not met yet (None in peers: refused by authip)


class UdpPeer(Client):
    """One source (address and port) of datagrams: a client to the router, whose replies go
    back from the face's socket.  sent: its recent requests by transaction id, [datagram,
    monotonic s, reply or None while outstanding], for the retransmissions."""
    listener = "udp"

    def __init__(self, sock: socket.socket, address: tuple, local: str,
                 face: FaceCounters) -> None:
        super().__init__(sock, address[0], format_address(address), local)
        self.address = address
        self.face = face
        self.sent: dict[int, list] = {}

    def send(self, frame: bytes) -> None:
        entry = self.sent.get(frame[0] << 8 | frame[1])
        if entry is not None:
            entry[2] = frame
        try:
            self.sock.sendto(frame, self.address)
        except OSError:
            pass            # a full buffer, an unreachable source: the client asks again

    def forward_target(self, tid: int, unit: int, yield_cpu: bool) -> Forward:
        return NO_FORWARD

    @property
    def at_rest(self) -> bool:
        return False

    def shutdown(self) -> None:
        pass                # nothing to end: the socket is the face's

    def close(self) -> None:
        self.closed = True


class UdpPort:
    """One socket on the udp-port (one per address of bind); ready() when it has input."""

    def __init__(self, sock: socket.socket, on_request, acl: AccessList, firewall: Firewall,
                 face: FaceCounters, stout_ms: int) -> None:
        """on_request(client, tid, unit, pdu): the router's; face: the listener's figures."""
        self.sock = sock
        self.fd = sock.fileno()
        self.local = format_address(sock.getsockname())
        self._on_request = on_request
        self._face = face
        self._stout_s = stout_ms / 1000
        self._acl = acl
        self._firewall = firewall
        self._renewed = False
        self.peers: dict[tuple, UdpPeer | None] = {}
        self.sources = 0            # the peers that are clients (not refused), for status

    def renew(self, acl: AccessList, firewall: Firewall, stout_ms: int) -> None:
        """Asyncio thread, at a reload: each source is judged again at its next datagram."""
        self._acl, self._firewall, self._stout_s = acl, firewall, stout_ms / 1000
        self._renewed = True

    def ready(self) -> None:
        """The face's home thread: the datagrams waiting, each answered, forwarded or
        dropped."""
        if self._renewed:
            self._renewed = False
            self.peers.clear()
            self.sources = 0
        sock = self.sock
        peers = self.peers
        for _ in range(DATAGRAMS_PER_TURN):
            try:
                data, address = sock.recvfrom(DATAGRAM_SIZE)
            except ConnectionRefusedError:      # a reply's ICMP error: read on
                continue
            except OSError:                     # nothing waits (or the socket is closed)
                return
            peer = peers.get(address, _NEW)
            if peer is _NEW:
                peer = self._meet(address)
            if peer is None:
                self._face.refused += 1
                continue
            assert isinstance(peer, UdpPeer)
            self._datagram(peer, data)

    def _meet(self, address: tuple) -> UdpPeer | None:
        """A new source: its client, or None when authip refuses it."""
        peers = self.peers
        if len(peers) >= MAX_PEERS:
            for known, peer in list(peers.items()):
                if peer is None or not peer.in_flight:
                    del peers[known]
                    self.sources -= peer is not None
        if not self._acl.allows(address[0]):
            peers[address] = None
            return None
        peer = UdpPeer(self.sock, address, self.local, self._face)
        peer.guard = self._firewall.guard(address[0], None, UdpPeer.listener)
        peers[address] = peer
        self.sources += 1
        return peer

    def _datagram(self, peer: UdpPeer, data: bytes) -> None:
        if len(data) <= HEADER_LEN:
            self._face.bad_frames += 1
            return
        tid, protocol, length, unit = HEADER.unpack_from(data)
        if frame_length(protocol, length) != len(data):
            self._face.bad_frames += 1
            return
        request = data[HEADER_LEN:]
        guard = peer.guard
        if guard is not None and not guard.allows(unit, request):
            peer.firewall_refused += 1
            self._face.refused += 1
            self._firewall.refused(guard, peer.peer, None, unit, request)   # counted, logged
            return
        now = time.monotonic()
        sent = peer.sent
        first = sent.get(tid)
        if first is not None and first[0] == data and now - first[1] < self._stout_s:
            self._face.retransmissions += 1
            if first[2] is not None:
                try:
                    self.sock.sendto(first[2], peer.address)
                except OSError:
                    pass
            return
        if peer.in_flight >= peer.max_in_flight:     # a TCP client would not be read now
            self._face.dropped += 1
            return
        if len(sent) >= MAX_REMEMBERED:
            for old in [t for t, entry in sent.items() if now - entry[1] >= self._stout_s]:
                del sent[old]
        sent[tid] = [data, now, None]
        peer.arrived_ns = time.monotonic_ns()
        self._on_request(peer, tid, unit, request)

    def close(self) -> None:
        self.sock.close()

