"""`--metrics ADDR:PORT`: the collector of mbgw.ops.metrics served on http://ADDR:PORT/metrics.

prometheus_client (Debian's python3-prometheus-client) does the exposition: its WSGI app is
served by wsgiref on one server per listening address, each in a daemon thread with a thread
per scrape: a client that is slow or vanishes costs its own connection (and thread) only,
until its read deadline.  At most MAX_SCRAPES connections at once, PER_ADDRESS of them from
one address (more are closed at once, logged once a minute per address); an accept() out of
descriptors rests the listener.
"""
import logging
import socket
import socketserver
import sys
import threading
import time
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer

from prometheus_client import CollectorRegistry, make_wsgi_app

from mbgw.net.address import parse_host_port
from mbgw.ops.limits import AcceptRest, WarnLimit, is_resource_error, share

log = logging.getLogger("mbgw.metrics")

IO_TIMEOUT_S = 10.0             # the longest a scrape's socket waits to read or write
MAX_SCRAPES = 16                # connections at once (a thread each) ...
PER_ADDRESS = share(MAX_SCRAPES)    # ... of which one address holds at most this many


# --- the HTTP side ---------------------------------------------------------------------------

class MetricsServer:
    """prometheus_client's WSGI app for a collector, on every address of ADDR:PORT."""

    def __init__(self, address: str, collector) -> None:
        self.address = address
        self.host, self.port = parse_host_port(address, "metrics")
        self.names: list[str] = []         # the listening addresses, once started
        self._collector = collector
        self._servers: list[_HttpServer] = []

    def start(self) -> list[str]:
        """Listen; returns the listening addresses.  Raises OSError if it cannot."""
        registry = CollectorRegistry(auto_describe=False)   # ours only: no process metrics
        registry.register(self._collector)
        app = _metrics_only(make_wsgi_app(registry))
        try:
            for family, sockaddr in _listening_addresses(self.host, self.port):
                self._servers.append(_HttpServer(family, sockaddr, app))
        except OSError:
            for server in self._servers:
                server.server_close()
            self._servers = []
            raise
        names = []
        for server in self._servers:
            host, port = server.socket.getsockname()[:2]
            names.append(f"[{host}]:{port}" if ":" in host else f"{host}:{port}")
            threading.Thread(target=server.serve_forever, name=f"metrics {port}",
                             daemon=True).start()
        return names

    def close(self) -> None:
        """Stop listening; a scrape under way finishes in its own thread."""
        for server in self._servers:
            # wakes serve_forever's select at once; shutdown() alone waits for its next poll
            server.socket.shutdown(socket.SHUT_RDWR)
            server.shutdown()
            server.server_close()
        self._servers = []


def _listening_addresses(host: str | None, port: int) -> list[tuple[int, tuple]]:
    """(family, socket address) of every address host:port names, None: every address of
    the machine (as asyncio's start_server)."""
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    return list(dict.fromkeys((family, sockaddr) for family, _, _, _, sockaddr in infos))


def _metrics_only(app):
    """app on GET and HEAD /metrics, with a Content-Length; 404 or 405 for anything else;
    a bug in a scrape costs that scrape only."""
    def metrics_app(environ, start_response):
        method = environ["REQUEST_METHOD"]
        if environ["PATH_INFO"] != "/metrics":
            return _refuse(start_response, "404 Not Found",
                           "not found: the metrics are on /metrics\n")
        if method not in ("GET", "HEAD"):
            return _refuse(start_response, "405 Method Not Allowed",
                           "only GET (or HEAD) /metrics\n")
        answer = []
        try:
            body = b"".join(app({**environ, "REQUEST_METHOD": "GET"},
                                lambda status, headers: answer.append((status, headers))))
        except Exception:      # a bug must cost one scrape, never the daemon
            log.exception("metrics: internal error")
            return _refuse(start_response, "500 Internal Server Error",
                           "internal error: see the daemon's log\n")
        status, headers = answer[0]
        start_response(status, [*headers, ("Content-Length", str(len(body)))])
        return [b""] if method == "HEAD" else [body]
    return metrics_app


def _refuse(start_response, status: str, text: str) -> list[bytes]:
    body = text.encode()
    start_response(status, [("Content-Type", "text/plain; charset=utf-8"),
                            ("Content-Length", str(len(body)))])
    return [body]


class _Handler(WSGIRequestHandler):
    timeout = IO_TIMEOUT_S      # a client that stalls loses its connection
    default_request_version = "HTTP/1.0"    # not 0.9: every answer has a status line

    def log_request(self, code="-", size="-") -> None:
        pass                    # a scrape is no event

    def log_message(self, format: str, *args) -> None:
        log.debug("metrics client %s: %s", self.client_address[0], format % args)


class _HttpServer(socketserver.ThreadingMixIn, WSGIServer):
    daemon_threads = True       # the daemon's stop waits for no scrape
    block_on_close = False

    def __init__(self, family: int, sockaddr: tuple, app) -> None:
        self.address_family = family
        self._lock = threading.Lock()
        self._open: dict[str, int] = {}         # connections by client address
        self._warn = WarnLimit(log)
        self._rest = AcceptRest(log, "metrics")
        super().__init__(sockaddr, _Handler, bind_and_activate=False)
        try:
            if family == socket.AF_INET6:   # [::] beside 0.0.0.0, as asyncio does
                self.socket.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            self.server_bind()
            self.server_activate()
        except OSError:
            self.server_close()
            raise
        self.set_app(app)

    def server_bind(self) -> None:
        # not HTTPServer's: its socket.getfqdn() may wait on DNS, which a gateway may lack
        socketserver.TCPServer.server_bind(self)
        host, self.server_port = self.server_address[:2]
        self.server_name = str(host)
        self.setup_environ()

    def get_request(self):
        try:
            accepted = super().get_request()
        except OSError as err:      # out of descriptors: rest, rather than spin in select()
            if is_resource_error(err):
                time.sleep(self._rest.failed(err))
            raise
        self._rest.accepted()
        return accepted

    def process_request(self, request, client_address) -> None:
        host = client_address[0]
        with self._lock:
            held = self._open.get(host, 0)
            full = held >= PER_ADDRESS or sum(self._open.values()) >= MAX_SCRAPES
            if not full:
                self._open[host] = held + 1
        if full:
            self._warn.warn(host, "full", "metrics: connection from %s refused: %d scrapes "
                            "under way (at most %d, %d an address)", host,
                            sum(self._open.values()), MAX_SCRAPES, PER_ADDRESS)
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._lock:
                host = client_address[0]
                self._open[host] -= 1
                if not self._open[host]:
                    del self._open[host]

    def handle_error(self, request, client_address) -> None:
        log.debug("metrics client %s: %s", client_address[0], sys.exception())
