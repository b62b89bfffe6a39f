"""Master mode's serial side: mbgw answers on the line for every serial address of the
slaveid table, as the proxy of the remote Modbus TCP servers.

One thread owns the line and the upstream connections.  It waits for a frame (no deadline;
the eventfd wakes it to stop) and:
- ignores a frame for an address outside the table, and the reply the slave it was for (if
  one is on the bus) sends next: the receiver is told to expect it (csrc/request.c);
- forwards a broadcast (address 0) with unit id 0 to every server of the table, and answers
  nothing (Serial Line V1.02, 2.1);
- forwards any other frame to its server and unit id with tcpto as the deadline, then writes
  the reply with the master's serial address.  No reply in time, or a reply that does not
  answer the request (another unit id, function or size, a bad MBAP header: logged at most
  once a minute per address and kind): 0x0B with `exception`, else silence; server
  unreachable: 0x0A, or silence.  If the master has sent something new in the meantime it
  has given up on the request, and the late answer is dropped;
- answers at once (0x0B with `exception`, else silence) a frame for an address that is down
  (demotion, mbgw.ops.device_stats), without a word to its server, unless a probe is due;
- answers a frame for the table address (`table-address`, with the table on) itself, from
  the exchange table (mbgw.table), once the line has been quiet for t3.5, as a serial slave
  of local data (VPGate 3.7); a broadcast is also written into the table.  The table slave
  counts its requests, invalid CRCs and lengths, and failed sends (VPGate 8.5).
A device that fails is closed, reopened when it is back (mbgw.line.supervisor), and reported
once per change.
Each serial address answered for has its statistics and health (mbgw.ops.device_stats), and the
traffic goes to `mbgw trace` while someone traces (mbgw.master.trace).  A new configuration
(SIGHUP) is taken between two transactions; new line settings reopen the line.
"""
import dataclasses
import logging
import os
import select
import ssl
import time

from mbgw.config.model import MasterConfig
from mbgw.errors import (
    BadReply,
    ChecksumError,
    ConfigError,
    FrameError,
    GatewayTimeout,
    LineTimeout,
    NoRoute,
    SerialError,
)
from mbgw.line import frames, native
from mbgw.line.framing import framing_for
from mbgw.line.port import SerialLine
from mbgw.line.supervisor import TURN_MARGIN_S, LineThread, longest_frame_s
from mbgw.master.trace import (
    OUTCOME_BAD_REPLY,
    OUTCOME_DEVICE_DOWN,
    OUTCOME_EXCEPTION,
    OUTCOME_REPLY,
    OUTCOME_TABLE,
    OUTCOME_TIMEOUT,
    OUTCOME_UNREACHABLE,
    MasterTracer,
)
from mbgw.ops.counters import MasterCounters, TableSlaveCounters
from mbgw.ops.device_stats import MASTER_COUNTS, DeviceTable, HealthRule
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.tls import client_context
from mbgw.ops.trace import TraceHub
from mbgw.protocol import pdu
from mbgw.upstream.pool import Interrupted, UpstreamPool, drain

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")

UNUSED_SETTINGS = {"stout_ms": 0, "nocheck": False}   # slave mode's: no reopen for them
# read at each answer: no reopen either
ANSWER_SETTINGS = {"interframe_ms": 0}
BAD_REPLY_LOG_INTERVAL_S = 60.0


def _line_settings(serial):
    return dataclasses.replace(serial, **UNUSED_SETTINGS, **ANSWER_SETTINGS)


def serial_functions(cfg: MasterConfig) -> tuple[int, ...]:
    """What the table's serial slave answers: its own list, else the table's."""
    return cfg.table.serial_functions or cfg.table.functions


def table_address(cfg: MasterConfig) -> int:
    """The serial address the table answers as; 0: none."""
    return cfg.table.address if cfg.table.enabled else 0


class SerialSlave(LineThread[MasterConfig]):
    def __init__(self, cfg: MasterConfig, line: SerialLine | None, counters: MasterCounters,
                 table=None) -> None:
        """table: the exchange table (mbgw.table.memory.Table), None in a gateway without."""
        super().__init__(cfg, line)
        self._table = cfg.slaveid
        self._counters = counters
        self._tcpto_ns = cfg.tcpto_ns
        self.devices = DeviceTable(MASTER_COUNTS, HealthRule(cfg.demotion))
        self._down = self.devices.rule.down    # the addresses that are down, by address
        self.trace = TraceHub()
        self.watch_raw(self.trace, answers=True)
        self._tracer = MasterTracer(self.trace)
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._pool = UpstreamPool(cfg.mdbport, cfg.max_connections, counters, self.wake_fd)
        self._pool.on_late = self._late
        self._tls_context: ssl.SSLContext | None = None
        self._use_tls(None, cfg)
        self._reply_to = b""       # the last frame for another slave: its reply may come next
        self._received_ns = 0       # when the request being answered was taken off the line
        self._bad_reply_logged: dict[tuple[int, str], float] = {}   # (address, kind): when
        self.table = table
        self.table_counters = TableSlaveCounters()
        self._table_address = table_address(cfg) if table is not None else 0
        self._rejected = -1     # the address of the frame a receive has just rejected
        if table is not None:
            self._responder = table.responder(serial_functions(cfg))
            table.watch_down(self._down)
        if line is not None:
            self._attach(line)
        else:
            self._detach()

    @property
    def turn_limit_s(self) -> float:
        """The longest request and the silence that ends it, tcpto with its server, the
        longest answer."""
        cfg = self._cfg
        s = cfg.serial
        end_ms = s.ascii_timeout_ms if s.protocol == "ascii" else s.end_of_frame_us / 1000
        return ((end_ms + sum(s.rtsdelays) + cfg.tcpto_ms + s.interframe_ms) / 1000
                + 2 * longest_frame_s(s) + TURN_MARGIN_S)

    def _attach(self, line: SerialLine) -> None:
        self._port = line.port
        self._framing = framing_for(line)
        serial = line.cfg
        self._receive = self._receive_ascii if serial.protocol == "ascii" else self._receive_rtu
        self._gap_us = serial.end_of_frame_us
        self._interchar_us = serial.ascii_timeout_ms * 1000
        # what an answer given at once waits after the request: t3.5 (RTU), in whole ms
        self._quiet_ms = -(-self._framing.inter_frame_us // 1000)
        # the longest ASCII frame at the line's speed, plus one inter-character pause
        self._ascii_frame_ns = (frames.ASCII_MAX_FRAME * serial.char_ns
                                + self._interchar_us * 1000)
        if self.table is not None:
            self.table.set_flags(line_down=False)

    def connections(self) -> list[dict]:
        """The open upstream connections (from any thread)."""
        return self._pool.connections()

    def stop(self) -> None:
        self._pool.stopping = True
        super().stop()

    # --- the line thread's hooks (mbgw.line.supervisor.LineThread) ---

    def _wake(self) -> None:
        os.eventfd_write(self.wake_fd, 1)

    def _detach(self) -> None:
        self._reply_to = b""
        if self.table is not None:
            self.table.set_flags(line_down=True)

    def _reopens(self, old, new) -> bool:
        return _line_settings(new) != _line_settings(old)

    def _configure(self, old: MasterConfig, reopen: bool) -> None:
        cfg = self._cfg
        self._table = cfg.slaveid
        self._tcpto_ns = cfg.tcpto_ns
        self._pool.reconfigure(cfg.mdbport, cfg.max_connections)
        try:
            self._use_tls(old, cfg)
        except ConfigError as err:
            log.error("TLS to servers: %s: the previous certificates stay in use", err)
        if self.table is not None:
            self._responder = self.table.responder(serial_functions(cfg))
            address = table_address(cfg)
            if address != self._table_address:
                self.table_counters.reset()     # a new slave (VPGate 8.5)
            self._table_address = address
        if cfg.demotion != old.demotion:
            self.devices.set_rule(cfg.demotion)
        if reopen:
            self._reply_to = b""

    def _use_tls(self, old: MasterConfig | None, cfg: MasterConfig) -> None:
        """The `tls` ranges' servers reached over TLS; a client context made again when the
        files changed.  Raises ConfigError."""
        upstream = cfg.upstream_tls
        if not (upstream.enabled and cfg.slaveid.tls_hosts):
            self._tls_context = None
        elif self._tls_context is None or old is None or old.upstream_tls != upstream:
            self._tls_context = client_context(upstream)
        self._pool.set_tls(self._tls_context, upstream.server_port, cfg.slaveid.tls_hosts,
                           cfg.slaveid.pins)

    def _turn(self) -> None:
        try:
            self._serve_next()
        except Interrupted:
            pass

    def _while_down(self, timeout_s: float) -> None:
        if select.select([self.wake_fd], [], [], timeout_s)[0]:
            drain(self.wake_fd)             # stopping, or a new configuration

    def close(self) -> None:
        """After the thread has ended (or if it never started)."""
        self._pool.close()
        if self._line is not None:
            self._line.close()
            self._line = None
        os.close(self.wake_fd)

    # --- receiving ---

    def _serve_next(self) -> None:
        self._rejected = -1
        try:
            adu = self._receive()
        except ChecksumError:
            self._counters.crc_errors += 1
            if self._table_address and self._rejected == self._table_address:
                self.table_counters.crc_errors += 1
            self._reply_to = b""
            return
        except (FrameError, LineTimeout):      # LineTimeout: noise, no ':' (ASCII)
            self._counters.invalid_frames += 1
            if self._table_address and self._rejected == self._table_address:
                self.table_counters.length_errors += 1
            self._reply_to = b""
            return
        if adu is None:
            return
        self._received_ns = time.monotonic_ns()
        if len(adu) < 2:
            self._counters.invalid_frames += 1
            if self._table_address and adu and adu[0] == self._table_address:
                self.table_counters.length_errors += 1
            return
        address = adu[0]
        if address == pdu.BROADCAST:
            self._reply_to = b""
            if self._table_address:
                self._broadcast_to_table(adu)
            self._broadcast(adu)
            return
        if address == self._table_address:
            self._reply_to = b""
            self._answer_from_table(adu)
            return
        route = self._table.route(address)
        if route is None:
            self._counters.other_addresses += 1
            self._reply_to = adu
            if self.trace.active:
                self._tracer.ignored(adu)
            return
        self._reply_to = b""
        self._forward(adu, *route)

    def _receive_rtu(self) -> bytes | None:
        try:
            return self._port.read_request(self.wake_fd, self._reply_to, self._gap_us,
                                           self.idle_ms)
        except (ChecksumError, FrameError):
            self._rejected = self._port.rejected_address
            raise

    def _receive_ascii(self) -> bytes | None:
        if self._port.idle_wait(self.wake_fd, self.idle_ms) != native.IDLE_INPUT:
            return None
        got = self._port.read_ascii(time.monotonic_ns() + self._ascii_frame_ns,
                                    self._interchar_us)
        if got.fault is not None:
            raise got.fault
        assert got.frame is not None
        try:
            return frames.ascii_decode(got.frame)
        except (ChecksumError, FrameError):
            self._rejected = _ascii_address(got.frame)
            raise

    # --- the exchange table's serial slave ---

    def _answer_from_table(self, adu: bytes) -> None:
        """A request for the table address: answered from the table once the line has been
        quiet for t3.5, unless the master moves on first."""
        counts = self.table_counters
        counts.requests += 1
        if _length_error(adu):
            counts.length_errors += 1       # the table answers it 0x03
        received_ns = time.monotonic_ns()
        reply = self._responder.answer(memoryview(adu)[1:])
        outcome = OUTCOME_TABLE
        if reply is not None:
            try:
                sent = self._answer(adu[0], reply, self._quiet_ms)
            except SerialError:
                counts.send_failures += 1
                raise
            if not sent:
                outcome += ", abandoned: the master moved on"
        if self.trace.active:
            self._tracer.table(adu, reply, outcome, (time.monotonic_ns() - received_ns) / 1e6)

    def _broadcast_to_table(self, adu: bytes) -> None:
        """A broadcast's writes go into the table too (its reads are ignored)."""
        self._responder.answer(memoryview(adu)[1:], True)
        if self.trace.active:
            self._tracer.table(adu, None, f"{OUTCOME_TABLE}: broadcast", 0.0)

    # --- forwarding ---

    def _forward(self, adu: bytes, host: str, unit: int) -> None:
        self._counters.requests += 1
        stats = self.devices.get(adu[0])
        if stats.upstream != (host, unit):
            stats.upstream = (host, unit)
        if self._down[adu[0]] and not stats.admit(time.monotonic()):
            self._refuse_as_down(adu, stats, host, unit)
            return
        stats.transactions += 1
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("line rx %s -> %s unit %d", adu.hex(" "), host, unit)
        tracing = self.trace.active
        if tracing:
            server, sent = self._pool.server(host), []

            def on_sent(conn, tid: int) -> None:
                sent.append((conn, tid))
                self._tracer.request(adu, server, conn, tid, unit)
            self._pool.on_sent = on_sent
        received_ns = time.monotonic_ns()
        reply, code = None, None
        reply_unit: int | None = unit
        try:
            reply = self._pool.transact(host, unit, adu[1:], received_ns + self._tcpto_ns)
        except GatewayTimeout:
            self._counters.timeouts += 1
            stats.timeouts += 1
            stats.failed()
            outcome, code = OUTCOME_TIMEOUT, pdu.GATEWAY_TARGET_FAILED
        except NoRoute:
            self._counters.unreachable += 1
            stats.unreachable += 1
            stats.failed()
            outcome, code = OUTCOME_UNREACHABLE, pdu.GATEWAY_PATH_UNAVAILABLE
        except BadReply as err:
            self._bad_reply(stats, host, unit, err)
            outcome, code = f"{OUTCOME_BAD_REPLY}: {err}", pdu.GATEWAY_TARGET_FAILED
            if err.pdu is not None:       # the server's frame, for the trace
                reply, reply_unit = err.pdu, err.unit
                latency_ms = (time.monotonic_ns() - received_ns) / 1e6
        else:
            exception = reply[0] & pdu.EXCEPTION_FLAG
            if exception:
                self._counters.device_exceptions += 1
            latency_ms = (time.monotonic_ns() - received_ns) / 1e6
            stats.answered(latency_ms, reply[1] if exception and len(reply) > 1 else None)
            outcome = OUTCOME_EXCEPTION if exception else OUTCOME_REPLY
        finally:
            if tracing:
                self._pool.on_sent = None
        answer = reply if code is None else gateway_exception(
            self._cfg.exception, adu[1], code, self._counters, stats)
        if answer is not None:
            if self._answer(adu[0], answer):
                if code is not None:
                    outcome += f", answered 0x{code:02x}"
            else:
                stats.abandoned += 1
                outcome += ", abandoned: the master moved on"
        if tracing:
            self._tracer.outcome(adu, server, sent[0] if sent else None, reply_unit, reply,
                                 outcome, None if reply is None else latency_ms)

    def _late(self, conn, tid: int, unit: int, reply: bytes) -> None:
        """The pool dropped a late reply (an earlier request's tid)."""
        if self.trace.active:
            self._tracer.late(self._pool.server(conn.host), conn, tid, unit, reply)

    def _refuse_as_down(self, adu: bytes, stats, host: str, unit: int) -> None:
        """The address is down and this is no probe: nothing goes to its server, the master
        gets 0x0B once the line has been quiet for t3.5 (with `exception`), else nothing."""
        self._counters.demoted_rejects += 1
        outcome = OUTCOME_DEVICE_DOWN
        answer = gateway_exception(self._cfg.exception, adu[1], pdu.GATEWAY_TARGET_FAILED,
                                   self._counters, stats)
        if answer is not None:
            if self._answer(adu[0], answer, self._quiet_ms):
                outcome += f", answered 0x{pdu.GATEWAY_TARGET_FAILED:02x}"
            else:
                stats.abandoned += 1
                outcome += ", abandoned: the master moved on"
        if self.trace.active:
            self._tracer.outcome(adu, self._pool.server(host), None, unit, None, outcome,
                                 None)

    def _bad_reply(self, stats, host: str, unit: int, err: BadReply) -> None:
        """Counted as the device's failure; a warning per address and kind of bad reply, at
        most once a minute (before the health change it may bring)."""
        setattr(stats, err.counter, getattr(stats, err.counter) + 1)
        key, now = (stats.address, err.counter), time.monotonic()
        if now - self._bad_reply_logged.get(key, -BAD_REPLY_LOG_INTERVAL_S) >= \
                BAD_REPLY_LOG_INTERVAL_S:
            self._bad_reply_logged[key] = now
            log.warning("device %d: the reply of server %s unit %d does not answer the "
                        "request (%s): dropped (replies of this kind for this address are "
                        "logged at most once a minute)", stats.address, self._pool.server(host),
                        unit, err)
        stats.failed()

    def _answer(self, address: int, answer, quiet_ms: int = 0) -> bool:
        """Write the answer on the line once it has been quiet for quiet_ms, and the
        interframe silence has passed since the request was taken, unless the master has
        moved on (False)."""
        interframe_ns = self._cfg.serial.interframe_ms * 1_000_000
        if interframe_ns:
            left_ns = self._received_ns + interframe_ns - time.monotonic_ns()
            quiet_ms = max(quiet_ms, -(-left_ns // 1_000_000))
        while (idle := self._port.idle_wait(self.wake_fd, quiet_ms)) != native.IDLE_TIMEOUT:
            if idle == native.IDLE_INPUT or self._stopping:
                self._counters.abandoned += 1
                return False
            # woken (and the signal taken) for a new configuration: it waits for this answer
        frame = bytes((address,)) + answer
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("line tx %s", frame.hex(" "))
        self._framing.send(frame)
        self._counters.replies += 1
        return True

    def _broadcast(self, adu: bytes) -> None:
        destinations = self._table.destinations
        if self.trace.active:
            self._pool.on_sent = lambda conn, tid: self._tracer.request(
                adu, f"{conn.host}:{conn.port}", conn, tid, pdu.BROADCAST)
        try:
            reached = self._pool.send_all(destinations, pdu.BROADCAST, adu[1:],
                                          time.monotonic_ns() + self._tcpto_ns)
        finally:
            self._pool.on_sent = None
        self._counters.broadcasts += 1        # counted once sent: its transaction is over
        stats = self.devices.get(pdu.BROADCAST)
        stats.transactions += 1
        stats.broadcasts += 1
        if reached < len(destinations):
            log.debug("broadcast reached %d of %d servers", reached, len(destinations))
        if self.trace.active:
            self._tracer.outcome(adu, None, None, pdu.BROADCAST, None,
                                 f"broadcast: {reached} of {len(destinations)} servers", None)


def _ascii_address(frame: bytes) -> int:
    """The address of an ASCII frame (':' and two hex digits), -1 when it has none."""
    try:
        return int(frame[1:3], 16)
    except ValueError:
        return -1


def _length_error(adu: bytes) -> bool:
    """The frame's length, or its byte count, is not what its function code and quantity say
    (VPGate 8.5 "invalid length")."""
    expected = frames.rtu_request_length(adu + b"\0\0")
    if expected != frames.LEN_UNKNOWN and expected != len(adu) + native.CRC_LEN:
        return True
    function = adu[1]
    if function in (0x0F, 0x10):
        quantity = int.from_bytes(adu[4:6], "big")
        return adu[6] != ((quantity + 7) // 8 if function == 0x0F else 2 * quantity)
    if function == 0x17:
        return adu[10] != 2 * int.from_bytes(adu[8:10], "big")
    return False
