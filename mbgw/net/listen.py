"""The listening sockets of a TCP server on one port, or the bound sockets of a UDP one:
every address bind resolves to; a server's plain and TLS ports on one bind address, moved
to another (`ServerPorts`)."""
import socket

from mbgw.errors import ListenError
from mbgw.net.address import format_address

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


class ServerPorts:
    """A server's listening sockets on one bind address: its port (`option` names the
    setting that gives it) and its TLS port, either None when not listened on.  The sockets
    are the caller's to poll; rebind() and the swaps happen on the server's own thread."""

    def __init__(self, bind: str | None, port: int | None, tls_port: int | None, *,
                 option: str) -> None:
        """Listens at once on both: raises ListenError, and nothing is left open."""
        self.bind = bind
        self.port = port
        self.tls_port = tls_port
        self.option = option
        self.plain, self.tls = self._listen_on(bind)

    def sockets(self) -> list[socket.socket]:
        return self.plain + self.tls

    def by_fd(self) -> dict[int, tuple[socket.socket, bool]]:
        """(listener, whether TLS) by fd."""
        return {**{s.fileno(): (s, False) for s in self.plain},
                **{s.fileno(): (s, True) for s in self.tls}}

    def addresses(self) -> list[str]:
        return [format_address(s.getsockname()) for s in self.plain] + \
            [f"{format_address(s.getsockname())} (TLS)" for s in self.tls]

    def listen_plain(self, port: int) -> list[socket.socket]:
        """New sockets on port at the bind address, for the caller to swap in (any thread).
        Raises ListenError."""
        return listen(self.bind, port, option=self.option)

    def listen_tls(self, port: int) -> list[socket.socket]:
        return listen(self.bind, port, option="tls-port")

    def rebind(self, bind: str | None) -> tuple[ListenError | None, ListenError | None]:
        """On bind instead, the caller having closed the sockets (the same port may not be
        listened on twice), else back on the old bind: (why the new bind failed, why the
        old one failed again, leaving none)."""
        self.plain = self.tls = []
        try:
            self.plain, self.tls = self._listen_on(bind)
            self.bind = bind
        except ListenError as err:
            try:
                self.plain, self.tls = self._listen_on(self.bind)
            except ListenError as again:
                return err, again
            return err, None
        return None, None

    def _listen_on(self, bind: str | None) -> tuple[list, list]:
        plain = listen(bind, self.port, option=self.option) if self.port is not None else []
        try:
            tls = listen(bind, self.tls_port, option="tls-port") \
                if self.tls_port is not None else []
        except ListenError:
            for sock in plain:
                sock.close()
            raise
        return plain, tls
