"""The listening sockets of a TCP server on one port, or the bound sockets of a UDP one:
every address bind resolves to."""
import socket

from mbgw.errors import ListenError

LISTEN_BACKLOG = 16


def listen(bind: str | None, port: int, *, option: str, stamp_arrivals=None,
           backlog: int = LISTEN_BACKLOG,
           kind: socket.SocketKind = socket.SOCK_STREAM) -> list[socket.socket]:
    """Non-blocking listening sockets on bind (None: every interface, IPv4 and IPv6) and
    port; kind SOCK_DGRAM: bound datagram sockets.  stamp_arrivals(fd), when given, is
    called on each before it listens (slave mode dates its connections' requests); backlog:
    listen()'s.  Raises ListenError naming option; nothing is left open then."""
    stream = kind == socket.SOCK_STREAM
    try:
        infos = socket.getaddrinfo(bind, port, socket.AF_UNSPEC, kind, 0, socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise ListenError(option, port, str(err)) from None
    sockets: list[socket.socket] = []
    try:
        for family, _, proto, _, address in dict.fromkeys(infos):
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            if stream:      # a datagram port reused would be shared with another program
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if stamp_arrivals is not None:
                stamp_arrivals(sock.fileno())
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
            if stream:
                sock.listen(backlog)
            sock.setblocking(False)
    except OSError as err:
        for sock in sockets:
            sock.close()
        raise ListenError(option, port, err) from None
    return sockets
