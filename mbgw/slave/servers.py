"""Remote Modbus TCP servers as targets (`[[route]] server = "IP[:PORT]"`): one thread,
mbgw-servers, with the upstream pool (one per port) and an Inbox per server.

Each Exchange is one transaction bounded by tcpto, connecting included: a reply (the server's
exception included) goes back as it came; a server that cannot be reached is 0x0A, no reply in
time (or one that does not answer the request) 0x0B, with `exception` on, else silence.  One
transaction at a time, in the order the exchanges came: a silent server holds the others for
tcpto at most.
"""
import logging
import os
import select
import threading
import time

from mbgw.config.model import SlaveConfig
from mbgw.errors import BadReply, GatewayTimeout, NoRoute
from mbgw.ops.counters import MasterCounters
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.trace import Outcome
from mbgw.protocol import pdu
from mbgw.routing.exchange import Exchange
from mbgw.routing.inbox import Inbox
from mbgw.upstream.pool import Interrupted, UpstreamPool

log = logging.getLogger("mbgw.tcp")

MAX_CONNECTIONS = 32       # per port, as master mode's default


def server_targets(cfg: SlaveConfig) -> dict[str, tuple[str, int]]:
    """The servers the routes reach, by their target label (RouteConfig.target)."""
    return {r.target: r.server for r in cfg.routes if r.server is not None}


class ServerTargets(threading.Thread):
    def __init__(self, servers: dict[str, tuple[str, int]], tcpto_ms: int,
                 exception: bool) -> None:
        super().__init__(name="mbgw-servers", daemon=True)
        self.servers = servers
        self.tcpto_ns = tcpto_ms * 1_000_000
        self.exception = exception
        self.counters = MasterCounters()
        self.inboxes = {label: Inbox() for label in servers}
        self._stop_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._stopping = False
        self._pools = {port: UpstreamPool(port, MAX_CONNECTIONS, self.counters, self._stop_fd)
                       for port in {port for _, port in servers.values()}}

    def stop(self) -> None:
        self._stopping = True
        self._pools_stopping()
        os.eventfd_write(self._stop_fd, 1)

    def _pools_stopping(self) -> None:
        for pool in self._pools.values():
            pool.stopping = True

    def run(self) -> None:
        poller = select.poll()
        by_fd = {}
        for label, inbox in self.inboxes.items():
            poller.register(inbox.wake_fd, select.POLLIN)
            by_fd[inbox.wake_fd] = label
        poller.register(self._stop_fd, select.POLLIN)
        try:
            while not self._stopping:
                for fd, _ in poller.poll():
                    ready = by_fd.get(fd)
                    if ready is not None:
                        for exchange in self.inboxes[ready].drain():
                            self._serve(ready, exchange)
        finally:
            for inbox in self.inboxes.values():      # what is left: refused
                for exchange in inbox.drain():
                    exchange.done(exchange, self._failure(exchange,
                                                          pdu.GATEWAY_PATH_UNAVAILABLE),
                                  Outcome.UNREACHABLE)
            for pool in self._pools.values():
                pool.close()

    def _serve(self, label: str, exchange: Exchange) -> None:
        if self._stopping:
            exchange.done(exchange, self._failure(exchange, pdu.GATEWAY_PATH_UNAVAILABLE),
                          Outcome.UNREACHABLE)
            return
        host, port = self.servers[label]
        pool = self._pools[port]
        deadline_ns = time.monotonic_ns() + self.tcpto_ns
        self.counters.requests += 1
        try:
            if exchange.address == pdu.BROADCAST:
                pool.send_all((host,), pdu.BROADCAST, exchange.pdu, deadline_ns)
                self.counters.broadcasts += 1
                reply, outcome = None, Outcome.BROADCAST
            else:
                reply = pool.transact(host, exchange.address, exchange.pdu, deadline_ns)
                self.counters.replies += 1
                outcome = Outcome.DEVICE_EXCEPTION if reply[0] & pdu.EXCEPTION_FLAG \
                    else Outcome.REPLY
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
            log.exception("internal error on a request to %s", label)
            reply, outcome = self._failure(exchange, pdu.GATEWAY_PATH_UNAVAILABLE), \
                Outcome.ERROR
        exchange.done(exchange, reply, outcome)

    def _failure(self, exchange: Exchange, code: int) -> bytes | None:
        if exchange.address == pdu.BROADCAST:
            return None
        return gateway_exception(self.exception, exchange.pdu[0], code, self.counters)

    def join_and_close(self) -> None:
        self.join()
        for inbox in self.inboxes.values():
            inbox.close()
        os.close(self._stop_fd)
