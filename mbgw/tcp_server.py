"""Slave mode's network side: the Modbus TCP server on mdbport.

authip is checked as soon as a connection is accepted, before any byte is read.  Beyond
max_connections the least recently active idle connection is closed for the newcomer; if
every connection has a request in flight, the newcomer is refused.
"""
import asyncio
import dataclasses
import itertools
import logging
import os
import socket
import threading
import time

from mbgw import mbap, pdu
from mbgw.acl import AccessList
from mbgw.config import SlaveConfig
from mbgw.counters import Counters
from mbgw.scheduler import OUTCOME_LINE_DOWN, OUTCOME_UNROUTABLE, Job, Queue, Scheduler
from mbgw.trace import TraceHub

log = logging.getLogger("mbgw.tcp")

MAX_IN_FLIGHT = 16          # TCP guide 4.4.2: a server holds 1..16 transactions per client
RECEIVE_SIZE = 4096         # what one read takes from a connection: 15 requests of 260 bytes
REFUSAL_LOG_INTERVAL_S = 60.0
_client_ids = itertools.count(1)


class Client(asyncio.BufferedProtocol):
    """One Modbus TCP connection.  Reads go into a buffer of its own (a plain Protocol gets
    each read as a new 256 KiB bytes object, which costs more than the rest of a request)."""

    def __init__(self, server: "TcpServer") -> None:
        self._server = server
        self.id = next(_client_ids)
        self.transport: asyncio.Transport | None = None
        self.peer = "?"
        self.local = "?"
        self.queue = Queue()
        self.in_flight = 0
        self.requests = 0
        self.connected_at = time.time()
        self.last_active = time.monotonic()
        self._buf = bytearray()                         # received, not yet a whole frame
        self._receive = memoryview(bytearray(RECEIVE_SIZE))
        self._paused = False
        self._fd = -1
        self._loop: asyncio.AbstractEventLoop | None = None
        # Replies are written straight from the line thread when nothing else is waiting to
        # go out; otherwise through the loop, in order.  The lock covers both, and in_flight
        # and _paused, which both threads change.
        self._write_lock = threading.Lock()
        self._queued_writes = 0

    def connection_made(self, transport) -> None:
        host = self.host = transport.get_extra_info("peername")[0]
        self.peer = format_address(transport.get_extra_info("peername"))
        self.local = format_address(transport.get_extra_info("sockname"))
        if not self._server.admit(self, host):
            transport.abort()
            return
        self.transport = transport
        self._loop = asyncio.get_running_loop()
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
            self._fd = sock.fileno()

    def connection_lost(self, exc) -> None:
        with self._write_lock:
            transport, self.transport = self.transport, None
        if transport is not None:
            self._server.forget(self)

    def get_buffer(self, sizehint: int) -> memoryview:
        return self._receive

    def buffer_updated(self, nbytes: int) -> None:
        if self.transport is None:
            return
        self._buf += self._receive[:nbytes]
        self.last_active = time.monotonic()
        try:
            for tid, unit, request in mbap.split_frames(self._buf):
                self.requests += 1
                self._server.request(self, tid, unit, request)
        except mbap.BadHeader as err:
            self._server.counters.connections_bad_header += 1
            log.warning("client %s: bad MBAP header (%s); closing the connection", self.peer, err)
            self.transport.abort()
            return
        with self._write_lock:
            pause = self.in_flight >= MAX_IN_FLIGHT and not self._paused
            self._paused |= pause
        if pause:
            self.transport.pause_reading()

    def submitted(self) -> None:
        with self._write_lock:
            self.in_flight += 1

    def write_now(self, frame: bytes) -> None:
        """Line thread: put a reply on the socket at once, sparing it a trip through the
        event loop (the loop wakes later for the bookkeeping: delivered())."""
        with self._write_lock:
            if self.transport is None:
                return
            if not self._queued_writes and self.transport.get_write_buffer_size() == 0:
                try:
                    sent = os.write(self._fd, frame)
                except BlockingIOError:
                    sent = 0
                except OSError:
                    return                     # the loop sees the broken connection
                if sent == len(frame):
                    return
                frame = frame[sent:]
            self._queued_writes += 1
            self._loop.call_soon_threadsafe(self._write_queued, frame)

    def _write_queued(self, frame: bytes) -> None:
        with self._write_lock:
            self._queued_writes -= 1
            if self.transport is not None:
                self.transport.write(frame)

    def _write(self, frame: bytes) -> None:
        """Loop thread: behind whatever the line thread queued."""
        with self._write_lock:
            if self._queued_writes:
                self._queued_writes += 1
                self._loop.call_soon(self._write_queued, frame)
            elif self.transport is not None:
                self.transport.write(frame)

    def finished(self, job: Job, reply: bytes | None) -> None:
        """Line thread: job's outcome is known; its reply (if any) goes out at once.  The loop
        is woken only when it has something to do (resume reading, trace): waking it for
        every reply would hold up the client that is just being woken to read it."""
        if reply is not None:
            self.write_now(mbap.frame(job.tid, job.unit, reply))
        with self._write_lock:
            self.in_flight -= 1
            connected = self.transport is not None
            resume = self._paused and self.in_flight < MAX_IN_FLIGHT and connected
            self._paused &= not resume
        if reply is not None and connected:
            self._server.counters.add("replies")
            self.last_active = time.monotonic()
        if resume or self._server.trace.active:
            self._loop.call_soon_threadsafe(self._after_reply, job, reply, resume)

    def _after_reply(self, job: Job, reply: bytes | None, resume: bool) -> None:
        if self._server.trace.active:
            self._server.traced(self, job.tid, job.unit, job.adu[1], reply, job.outcome,
                                job.received_ns)
        if resume and self.transport is not None:
            self.transport.resume_reading()

    def send(self, tid: int, unit: int, reply: bytes | None) -> None:
        if reply is not None and self.transport is not None:
            self._write(mbap.frame(tid, unit, reply))
            self._server.counters.add("replies")
            self.last_active = time.monotonic()


class TcpServer:
    def __init__(self, cfg: SlaveConfig, scheduler: Scheduler, counters: Counters,
                 line_up) -> None:
        self._cfg = cfg
        self._scheduler = scheduler
        self.counters = counters
        self._line_up = line_up          # callable: is the serial line usable?
        self._acl = AccessList(cfg.authip)
        self.clients: list[Client] = []
        self._refusals: dict[str, float] = {}
        self._server: asyncio.base_events.Server | None = None
        self.trace = TraceHub()

    async def start(self) -> list[str]:
        """Listen; returns the listening addresses."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: Client(self), host=self._cfg.bind,
                                                port=self._cfg.mdbport, reuse_address=True)
        return self.addresses()

    def addresses(self) -> list[str]:
        return [format_address(s.getsockname()) for s in self._server.sockets]

    async def reconfigure(self, cfg: SlaveConfig) -> None:
        """Apply new settings; connections they do not concern stay open."""
        old, self._cfg = self._cfg, cfg
        self._acl = AccessList(cfg.authip)
        for client in list(self.clients):
            if not self._acl.allows(client.host):
                log.info("client %s closed: no longer allowed by authip", client.peer)
                client.transport.abort()
        if (cfg.mdbport, cfg.bind) != (old.mdbport, old.bind):
            self._server.close()
            try:
                await self.start()
            except OSError as err:
                log.error("cannot listen on port %d (%s): staying on port %d", cfg.mdbport,
                          err.strerror, old.mdbport)
                self._cfg = dataclasses.replace(cfg, mdbport=old.mdbport, bind=old.bind)
                await self.start()
            log.info("now listening on %s", ", ".join(self.addresses()))

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for client in list(self.clients):
            client.transport.abort()

    def admit(self, client: Client, host: str) -> bool:
        if not self._acl.allows(host):
            self.counters.connections_refused_authip += 1
            self._log_refusal(host)
            return False
        if len(self.clients) >= self._cfg.max_connections:
            idle = [c for c in self.clients if c.in_flight == 0]
            if not idle:
                self.counters.connections_refused_limit += 1
                log.warning("client %s refused: all %d connections are busy",
                            client.peer, len(self.clients))
                return False
            victim = min(idle, key=lambda c: c.last_active)
            log.info("client %s closed to make room for %s", victim.peer, client.peer)
            self.counters.connections_evicted += 1
            victim.transport.abort()
            self.forget(victim)
            victim.transport = None
        self.counters.connections_accepted += 1
        self.clients.append(client)
        log.debug("client %s connected", client.peer)
        return True

    def close_client(self, client_id: int) -> bool:
        """Force-close a client connection (operator's command)."""
        for client in self.clients:
            if client.id == client_id:
                log.info("client %s closed by the operator", client.peer)
                client.transport.abort()
                return True
        return False

    def forget(self, client: Client) -> None:
        if client in self.clients:
            self.clients.remove(client)
            self._scheduler.discard(client.queue)
            log.debug("client %s disconnected", client.peer)

    def _log_refusal(self, host: str) -> None:
        now = time.monotonic()
        if now - self._refusals.get(host, -REFUSAL_LOG_INTERVAL_S) >= REFUSAL_LOG_INTERVAL_S:
            self._refusals[host] = now
            log.warning("connection from %s refused: not in authip (further refusals of this "
                        "address are logged at most once a minute)", host)

    def request(self, client: Client, tid: int, unit: int, request: bytes) -> None:
        self.counters.requests += 1
        tracing = self.trace.active
        received_ns = time.monotonic_ns() if tracing else 0
        if tracing:
            self.trace.emit(self._event("request", client, tid, unit, request, "", None))
        address = self._cfg.slaveid or unit
        if address > pdu.MAX_SERIAL_ADDRESS:
            self.counters.unroutable += 1
            self._refuse(client, tid, unit, request, OUTCOME_UNROUTABLE, received_ns)
            return
        if not self._line_up():
            self.counters.add("line_down_rejects")
            self._refuse(client, tid, unit, request, OUTCOME_LINE_DOWN, received_ns)
            return
        client.submitted()
        self._scheduler.submit(client.queue, Job(client, tid, unit, bytes((address,)) + request,
                                                 received_ns))

    def _refuse(self, client: Client, tid: int, unit: int, request: bytes, outcome: str,
                received_ns: int) -> None:
        reply = self._path_unavailable(request[0])
        client.send(tid, unit, reply)
        if self.trace.active:
            self.traced(client, tid, unit, request[0], reply, outcome, received_ns)

    def traced(self, client: Client, tid: int, unit: int, function: int, reply: bytes | None,
               outcome: str, received_ns: int) -> None:
        latency_ms = (time.monotonic_ns() - received_ns) / 1e6 if received_ns else None
        if reply is None:
            self.trace.emit(self._event("no reply", client, tid, unit, bytes((function,)),
                                        outcome, latency_ms))
        else:
            self.trace.emit(self._event("reply", client, tid, unit, reply, outcome, latency_ms))

    @staticmethod
    def _event(direction: str, client: Client, tid: int, unit: int, data: bytes,
               outcome: str, latency_ms) -> dict:
        return {"time": time.time(), "direction": direction, "client": client.id,
                "peer": client.peer, "local": client.local, "tid": tid, "unit": unit,
                "function": data[0], "length": len(data) if direction != "no reply" else 0,
                "pdu": data.hex() if direction != "no reply" else "", "outcome": outcome,
                "latency_ms": latency_ms}

    def _path_unavailable(self, function: int) -> bytes | None:
        if not self._cfg.exception:
            return None
        self.counters.add("gateway_exceptions")
        return pdu.exception_pdu(function, pdu.GATEWAY_PATH_UNAVAILABLE)


def format_address(name) -> str:
    host, port = name[:2]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
