"""Remote Modbus TCP servers as targets (`[[route]] server = "IP[:PORT]"`): a thread per
server (mbgw-server HOST:PORT), each with its own upstream connection and an Inbox.

Each Exchange is one transaction bounded by tcpto, connecting included: a reply (the server's
exception included) goes back as it came; a server that cannot be reached is 0x0A, no reply in
time (or one that does not answer the request) 0x0B, with `exception` on, else silence.  One
transaction at a time per server, in the order the exchanges came; a silent server holds up
only its own requests.  A route's `tls = true` server is reached over TLS as a serial face
reaches it (mbgw.upstream.tls_choice).
"""
import logging
import os
import select
import threading
import time

from mbgw.config.lines import RouteConfig
from mbgw.config.model import SlaveConfig, UpstreamTlsConfig
from mbgw.errors import BadReply, GatewayTimeout, NoRoute
from mbgw.ops.counters import MasterCounters
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.trace import Outcome
from mbgw.protocol import pdu
from mbgw.routing.queue import Exchange, Inbox
from mbgw.upstream.pool import Interrupted, UpstreamPool
from mbgw.upstream.tls_choice import ClientTls, routes_tls

log = logging.getLogger("mbgw.tcp")

MAX_CONNECTIONS = 32       # per port, as master mode's default
# What status and /metrics show of each server: the counters its thread and its pool keep
SERVER_FIGURES = ("requests", "replies", "device_exceptions", "gateway_exceptions", "timeouts",
                  "unreachable", "broadcasts", "late_replies", "wrong_unit", "wrong_function",
                  "connections_opened", "connections_evicted", "connections_lost",
                  "connections_bad_header")


def server_targets(cfg: SlaveConfig) -> dict[str, RouteConfig]:
    """The servers the routes reach, by their target label (RouteConfig.target): each the
    route that reaches it (its server, tls, fingerprint)."""
    return {r.target: r for r in cfg.routes if r.server is not None}


def how_reached(servers: dict[str, RouteConfig]) -> dict[str, tuple]:
    """What the servers' threads are made of (not the routes' units): a change to it makes
    them anew at a reload."""
    return {label: (r.server, r.tls, r.fingerprint) for label, r in servers.items()}


class ServerTargets:
    """Every server the routes reach, each served by a thread of its own."""

    def __init__(self, servers: dict[str, RouteConfig], tcpto_ms: int, exception: bool,
                 upstream_tls: UpstreamTlsConfig) -> None:
        """Raises ConfigError (the TLS client files of a `tls` route)."""
        self.threads = {label: ServerThread(label, route, tcpto_ms, exception, upstream_tls)
                        for label, route in servers.items()}
        self.inboxes = {label: thread.inbox for label, thread in self.threads.items()}

    def status(self) -> list[dict]:
        """Each server's figures (ServerThread.status), from any thread."""
        return [thread.status() for thread in self.threads.values()]

    def start(self) -> None:
        for thread in self.threads.values():
            thread.start()

    def stop(self) -> None:
        for thread in self.threads.values():
            thread.stop()

    def join_and_close(self) -> None:
        for thread in self.threads.values():
            thread.join_and_close()


class ServerThread(threading.Thread):
    """One server's transactions, one at a time, on its own connection."""

    def __init__(self, label: str, route: RouteConfig, tcpto_ms: int, exception: bool,
                 upstream_tls: UpstreamTlsConfig) -> None:
        super().__init__(name=f"mbgw-{label}", daemon=True)
        self.label = label
        assert route.server is not None
        self.address = label.removeprefix("server ")      # HOST:PORT, [IPv6]:PORT
        self.host, port = route.server
        self.tcpto_ns = tcpto_ms * 1_000_000
        self.exception = exception
        self.counters = MasterCounters()
        self.inbox = Inbox()
        self._stop_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._stopping = False
        self._pool = UpstreamPool(port, MAX_CONNECTIONS, self.counters, self._stop_fd)
        ClientTls().reach(self._pool, upstream_tls, port, *routes_tls((route,), port))

    def stop(self) -> None:
        self._stopping = True
        self._pool.stopping = True
        os.eventfd_write(self._stop_fd, 1)

    def status(self) -> dict:
        """The server as status and /metrics show it: HOST:PORT, its figures and its open
        connections (read from any thread while this one counts)."""
        counters = self.counters
        return {"server": self.address,
                "counters": {name: getattr(counters, name) for name in SERVER_FIGURES},
                "connections": self._pool.connections()}

    def run(self) -> None:
        poller = select.poll()
        poller.register(self.inbox.wake_fd, select.POLLIN)
        poller.register(self._stop_fd, select.POLLIN)
        try:
            while not self._stopping:
                for fd, _ in poller.poll():
                    if fd == self.inbox.wake_fd:
                        for exchange in self.inbox.drain():
                            self._serve(exchange)
        finally:
            for exchange in self.inbox.drain():      # what is left: refused
                exchange.done(exchange, self._failure(exchange, pdu.GATEWAY_PATH_UNAVAILABLE),
                              Outcome.UNREACHABLE)
            self._pool.close()

    def _serve(self, exchange: Exchange) -> None:
        if self._stopping:
            exchange.done(exchange, self._failure(exchange, pdu.GATEWAY_PATH_UNAVAILABLE),
                          Outcome.UNREACHABLE)
            return
        deadline_ns = time.monotonic_ns() + self.tcpto_ns
        self.counters.requests += 1
        try:
            reply, outcome = self._transact(exchange, deadline_ns)
        except NoRoute:
            self.counters.unreachable += 1
            reply, outcome = self._failure(exchange, pdu.GATEWAY_PATH_UNAVAILABLE), \
                Outcome.UNREACHABLE
        except (GatewayTimeout, BadReply):
            self.counters.timeouts += 1
            reply, outcome = self._failure(exchange, pdu.GATEWAY_TARGET_FAILED), Outcome.TIMEOUT
        except Interrupted:
            reply, outcome = self._failure(exchange, pdu.GATEWAY_PATH_UNAVAILABLE), \
                Outcome.UNREACHABLE
        except Exception:   # a bug must cost one request, never the thread
            log.exception("internal error on a request to %s", self.label)
            reply, outcome = self._failure(exchange, pdu.GATEWAY_PATH_UNAVAILABLE), \
                Outcome.ERROR
        exchange.done(exchange, reply, outcome)

    def _transact(self, exchange: Exchange, deadline_ns: int) -> tuple[bytes | None, str]:
        if exchange.address == pdu.BROADCAST:
            self._pool.send_all((self.host,), pdu.BROADCAST, exchange.pdu, deadline_ns)
            self.counters.broadcasts += 1
            return None, Outcome.BROADCAST
        reply = self._pool.transact(self.host, exchange.address, exchange.pdu, deadline_ns)
        self.counters.replies += 1
        if reply[0] & pdu.EXCEPTION_FLAG:
            self.counters.device_exceptions += 1
            return reply, Outcome.DEVICE_EXCEPTION
        return reply, Outcome.REPLY

    def _failure(self, exchange: Exchange, code: int) -> bytes | None:
        if exchange.address == pdu.BROADCAST:
            return None
        return gateway_exception(self.exception, exchange.pdu[0], code, self.counters)

    def join_and_close(self) -> None:
        if self.is_alive():
            self.join()
        self.inbox.close()
        os.close(self._stop_fd)
