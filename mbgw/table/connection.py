"""A table server's client connection, and the rules the server keeps its clients by: which
one a newcomer takes the place of when the server is full, and which is too late with a
request (each client's deadlines)."""
import socket
import time

from mbgw.firewall.guard import Guard
from mbgw.ops.limits import FIRST_REQUEST_S, SLOW_REQUEST_S


class Connection:
    """A table client: its socket, what of a request it has sent and what of its replies the
    socket has not taken, and the bookkeeping the limits and the status read."""
    __slots__ = ("sock", "fd", "peer", "partial", "held", "connected_at", "requests", "host",
                 "role", "listener", "guard", "firewall_refused", "tls", "opened",
                 "partial_since", "id", "last_active")

    def __init__(self, sock: socket.socket, peer: str, host: str = "",
                 role: str | None = None, tls: bool = False) -> None:
        self.host = host
        self.role = role                    # the firewall's view of it (TLS sets a role)
        self.tls = tls                      # sock is an SSLSocket
        self.listener = "tls" if tls else "plain"
        self.guard: Guard | None = None
        self.firewall_refused = 0
        self.sock = sock
        self.fd = sock.fileno()
        self.peer = peer
        self.partial = bytearray()      # the start of a frame the next read completes
        self.held = bytearray()         # replies the socket has not taken yet
        self.connected_at = time.time()
        self.opened = time.monotonic()
        self.partial_since = 0.0        # monotonic: when the frame in partial began
        self.requests = 0
        self.id = 0                     # the operator's handle (mbgw clients), set on adoption
        self.last_active = self.opened  # monotonic: its last read


def eviction_victim(pool: list[Connection], now: float) -> Connection | None:
    """The client a newcomer takes the place of: the longest connected of those that never
    sent a whole request, else of those slow with one; never one whose replies wait in its
    socket.  None when there is none."""
    victims = [c for c in pool if not c.requests and not c.held] or \
        [c for c in pool if c.partial_since and now - c.partial_since >= SLOW_REQUEST_S
         and not c.held]
    return min(victims, key=lambda c: c.opened, default=None)


def late(client: Connection, now: float, request_timeout_s: float) -> str | None:
    """Why the client is closed now: a request not whole within request_timeout_s of its first
    byte, or no request within FIRST_REQUEST_S of connecting; None while it is in time."""
    if client.partial_since and now - client.partial_since > request_timeout_s:
        return f"a request not whole within request-timeout ({request_timeout_s * 1000:.0f} ms)"
    if not client.requests and now - client.opened > FIRST_REQUEST_S:
        return f"no request within {FIRST_REQUEST_S:g} s"
    return None
