"""The console's connections before and around aiohttp: its own listening sockets, so that
each newcomer meets the limits before any byte is read or any TLS work is done.

At most MAX_CONNECTIONS connections (TLS handshakes included), PER_ADDRESS of them from one
address; a newcomer over either takes the place of an idle connection (no request under
way; one that never sent a request first, else the least recently used), or is closed.  A
connection must bring its first whole request within request-timeout (the TLS handshake
included) and later ones within KEEPALIVE_S, or it is closed.  accept() failing for want of
descriptors rests the listener (mbgw.ops.limits), never spinning.  With HTTPS, the first
byte tells TLS (a handshake record) from plain HTTP, which https-only answers with a
redirect to the same address over HTTPS, and which is closed otherwise."""
import asyncio
import logging
import re
import socket
import ssl
import time

from aiohttp import web

from mbgw.ops.limits import AcceptRest, WarnLimit, share

log = logging.getLogger("mbgw.web")

MAX_CONNECTIONS = 64
PER_ADDRESS = share(MAX_CONNECTIONS)
KEEPALIVE_S = 15.0                  # an idle keep-alive connection is closed after this
LISTEN_BACKLOG = 128
TLS_HANDSHAKE = 0x16                # the first byte of a TLS ClientHello record
REDIRECT_HEAD_MAX = 4096            # the plain request a redirect reads, at most
_HOST = re.compile(r"^[A-Za-z0-9.\-]+$|^\[[0-9A-Fa-f:.]+\]$")


class Connection:
    __slots__ = ("host", "sock", "opened", "used", "handler", "task", "timer", "busy",
                 "requests", "head")

    def __init__(self, host: str, sock: socket.socket) -> None:
        self.host = host
        self.sock = sock
        self.opened = self.used = time.monotonic()
        self.handler: web.RequestHandler | None = None   # once aiohttp has it
        self.task: asyncio.Task | None = None            # handing over (the TLS handshake)
        self.timer: asyncio.TimerHandle | None = None
        self.busy = 0                   # requests under way
        self.requests = 0
        self.head = b""                 # a plain request read for its redirect

    @property
    def idle(self) -> bool:
        return self.handler is not None and not self.busy


class _Tracked(web.Server):
    """aiohttp's low-level server, telling the gate when a connection ends."""

    def __init__(self, gate: "Gate", *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._gate = gate

    def connection_lost(self, handler, exc=None) -> None:
        super().connection_lost(handler, exc)
        self._gate.lost(handler)


class Gate:
    def __init__(self, runner: web.AppRunner, context: ssl.SSLContext | None,
                 https_only: bool, timeout_s: float) -> None:
        self._loop = asyncio.get_running_loop()
        base = runner.server
        assert base is not None
        self.server = _Tracked(self, base.request_handler, request_factory=base.request_factory,
                               loop=self._loop, access_log=None, keepalive_timeout=KEEPALIVE_S)
        self._context = context
        self._https_only = https_only
        self.timeout_s = timeout_s
        self._listeners: list[socket.socket] = []
        self._connections: dict[Connection, None] = {}      # in the order they came
        self._by_handler: dict[web.RequestHandler, Connection] = {}
        self._rest = AcceptRest(log, "web console")
        self._warn = WarnLimit(log)
        self.refused = self.evicted = self.timed_out = 0

    @property
    def connections(self) -> int:
        return len(self._connections)

    def listen(self, host: str | None, port: int) -> list[str]:
        """Listen on every address of host (None: all) and port; raises OSError."""
        infos = socket.getaddrinfo(host, port, socket.AF_UNSPEC, socket.SOCK_STREAM, 0,
                                   socket.AI_PASSIVE)
        try:
            for family, kind, proto, _, address in dict.fromkeys(infos):
                sock = socket.socket(family, kind, proto)
                self._listeners.append(sock)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6:
                    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                sock.bind(address)
                sock.listen(LISTEN_BACKLOG)
                sock.setblocking(False)
        except OSError:
            self.stop_listening()
            raise
        for sock in self._listeners:
            self._loop.add_reader(sock.fileno(), self._accept, sock)
        names = []
        for sock in self._listeners:
            name, bound = sock.getsockname()[:2]
            names.append(f"[{name}]:{bound}" if ":" in name else f"{name}:{bound}")
        return names

    def stop_listening(self) -> None:
        for sock in self._listeners:
            if sock.fileno() >= 0:
                self._loop.remove_reader(sock.fileno())
            sock.close()
        self._listeners = []

    async def close(self, timeout_s: float) -> None:
        self.stop_listening()
        for connection in list(self._connections):
            if connection.handler is None:
                self._close(connection)
        await self.server.shutdown(timeout_s)
        for connection in list(self._connections):
            self._close(connection)

    # --- admission ---

    def _accept(self, listener: socket.socket) -> None:
        accepted = self._rest.accept(listener, lambda rest_s: self._rest_listener(listener,
                                                                                  rest_s))
        if accepted is None:
            return
        sock, address = accepted
        host = address[0]
        if not self._room_for(host):
            sock.close()
            return
        connection = Connection(host, sock)
        self._connections[connection] = None
        connection.timer = self._loop.call_later(self.timeout_s, self._first_due, connection)
        sock.setblocking(False)
        if self._context is None:
            self._hand_over(connection, None)
        else:
            self._loop.add_reader(sock.fileno(), self._sniff, connection)

    def _rest_listener(self, listener: socket.socket, rest_s: float) -> None:
        self._loop.remove_reader(listener.fileno())
        self._loop.call_later(rest_s, self._resume, listener)

    def _resume(self, listener: socket.socket) -> None:
        if listener in self._listeners:
            self._loop.add_reader(listener.fileno(), self._accept, listener)

    def _room_for(self, host: str) -> bool:
        """Whether a newcomer from host fits, an idle connection closed for it if need be."""
        mine = [c for c in self._connections if c.host == host]
        if len(mine) >= PER_ADDRESS:
            pool, why = mine, f"{PER_ADDRESS} connections of this address open"
        elif len(self._connections) >= MAX_CONNECTIONS:
            pool, why = list(self._connections), f"{MAX_CONNECTIONS} connections open"
        else:
            return True
        idle = [c for c in pool if c.idle]
        if not idle:
            self.refused += 1
            self._warn.warn(host, "full", "web console: connection from %s refused: %s, none "
                            "idle", host, why)
            return False
        victim = min(idle, key=lambda c: (c.requests > 0, c.used))
        self.evicted += 1
        self._close(victim)
        return True

    def _first_due(self, connection: Connection) -> None:
        connection.timer = None
        if connection.requests or connection not in self._connections:
            return
        self.timed_out += 1
        self._warn.warn(connection.host, "timeout", "web console: connection from %s closed: "
                        "no whole request within request-timeout (%d ms)", connection.host,
                        self.timeout_s * 1000)
        self._close(connection)

    # --- TLS or plain ---

    def _sniff(self, connection: Connection) -> None:
        """The first byte: a TLS handshake is handed over; plain HTTP is redirected
        (https-only) or closed."""
        fd = connection.sock.fileno()
        try:
            first = connection.sock.recv(1, socket.MSG_PEEK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            first = b""
        if first and first[0] == TLS_HANDSHAKE:
            self._loop.remove_reader(fd)
            self._hand_over(connection, self._context)
        elif first and self._https_only:
            self._loop.remove_reader(fd)
            self._loop.add_reader(fd, self._read_head, connection)
            self._read_head(connection)
        else:
            self._close(connection)

    def _read_head(self, connection: Connection) -> None:
        try:
            data = connection.sock.recv(REDIRECT_HEAD_MAX - len(connection.head))
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._close(connection)
            return
        connection.head += data
        if b"\r\n\r\n" not in connection.head and len(connection.head) < REDIRECT_HEAD_MAX:
            return
        location = redirect_location(connection.head, connection.sock.getsockname())
        try:
            connection.sock.send(
                b"HTTP/1.1 308 Permanent Redirect\r\nLocation: " + location.encode()
                + b"\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
        except OSError:
            pass
        connection.requests += 1
        self._close(connection)

    def _hand_over(self, connection: Connection, context: ssl.SSLContext | None) -> None:
        def protocol():
            handler = self.server()
            connection.handler = handler
            self._by_handler[handler] = connection
            return handler
        coroutine = self._loop.connect_accepted_socket(
            protocol, connection.sock, ssl=context,
            ssl_handshake_timeout=self.timeout_s if context is not None else None)
        connection.task = self._loop.create_task(coroutine)
        connection.task.add_done_callback(lambda task: self._handed_over(connection, task))

    def _handed_over(self, connection: Connection, task: asyncio.Task) -> None:
        connection.task = None
        if task.cancelled() or task.exception() is not None:
            if not task.cancelled():
                log.debug("web console: connection from %s: %s", connection.host,
                          task.exception())
            connection.sock.close()         # the transport's own: closing twice is nothing
            self._forget(connection)

    # --- the requests (the server's middleware) and the end ---

    def began(self, handler) -> None:
        connection = self._by_handler.get(handler)
        if connection is not None:
            connection.busy += 1
            connection.requests += 1

    def ended(self, handler) -> None:
        connection = self._by_handler.get(handler)
        if connection is not None:
            connection.busy -= 1
            connection.used = time.monotonic()

    def lost(self, handler) -> None:
        connection = self._by_handler.get(handler)
        if connection is not None:
            self._forget(connection)

    def _close(self, connection: Connection) -> None:
        if connection.handler is not None:
            connection.handler.force_close()
        elif connection.task is not None:
            connection.task.cancel()
        else:
            fd = connection.sock.fileno()
            if fd >= 0:
                self._loop.remove_reader(fd)
            connection.sock.close()
        self._forget(connection)

    def _forget(self, connection: Connection) -> None:
        if connection.timer is not None:
            connection.timer.cancel()
            connection.timer = None
        self._connections.pop(connection, None)
        if connection.handler is not None:
            self._by_handler.pop(connection.handler, None)
        if connection.task is None and connection.handler is None:
            connection.sock.close()


def redirect_location(head: bytes, local) -> str:
    """https:// and the host and path a plain HTTP request named (the host without its port:
    the console's port is the same), or the console's own address."""
    lines = head.split(b"\r\n")
    parts = lines[0].split(b" ")
    path = parts[1].decode("latin-1") if len(parts) >= 2 else "/"
    if not path.startswith("/") or any(c in path for c in "\r\n \\"):
        path = "/"
    host = ""
    for line in lines[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"host":
            host = value.strip().decode("latin-1")
            break
    if host.startswith("["):
        host = host[:host.find("]") + 1]
    else:
        host = host.rsplit(":", 1)[0]
    if not _HOST.match(host):
        address = local[0]
        host = f"[{address}]" if ":" in address else address
    return f"https://{host}:{local[1]}{path}"
