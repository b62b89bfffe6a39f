"""A serial face: a line in master mode, where an outside master polls serial addresses and
mbgw answers for each address a route takes (mbgw.master.face_routes), as the proxy of its
target.

One thread owns the line, the upstream connections and the wait for other lines' answers.
It waits for a frame (no deadline; the eventfd wakes it to stop) and:
- ignores a frame for an address no route takes, and the reply the slave it was for (if one
  is on the bus) sends next: the receiver is told to expect it (csrc/request.c);
- forwards a broadcast (address 0) with unit id 0 to every server the face reaches, and
  writes it into the table when the face reaches the table; it answers nothing (Serial Line
  V1.02, 2.1).  A broadcast never goes to another line: its devices were not given to this
  master;
- forwards a frame routed to a server to its unit id with tcpto as the deadline
  (mbgw.master.server_forward), then writes the reply with the master's serial address.
  No reply in time, or a reply that does not answer the request (another unit id, function
  or size, a bad MBAP header: logged at most once a minute per address and kind): 0x0B
  with `exception`, else silence; server unreachable: 0x0A, or silence.  If the master has
  sent something new in the meantime it has given up on the request, and the late answer
  is dropped;
- answers at once (0x0B with `exception`, else silence) a frame for an address that is down
  (demotion, mbgw.ops.device_stats), without a word to its server, unless a probe is due;
- hands a frame routed to a line in slave mode to that line's thread (mbgw.routing: an
  Exchange in its Inbox) and writes what it answers; a line that does not answer within its
  safety bound is 0x0B (or silence); a line that is not running, 0x0A (or silence);
- answers a frame routed to the table from the exchange table once the line has been quiet
  for t3.5 (mbgw.master.table_slave), and one for `[general] gateway-unit` the same way,
  with the table's identity functions only (FC 8, 17, 43/14; any other is 0x01).
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
import time

from mbgw.config.lines import LineConfig
from mbgw.config.model import SerialConfig
from mbgw.config.route_plan import RouteMap
from mbgw.errors import ChecksumError, FrameError, Interrupted, LineTimeout
from mbgw.line import native
from mbgw.line.serial_line import SerialLine
from mbgw.line.supervisor import TURN_MARGIN_S, LineThread, longest_frame_s, open_at_start
from mbgw.master.face_routes import (
    GATEWAY,
    LINE,
    SERVER,
    TABLE,
    FaceSettings,
    Hop,
    build_hops,
    face_settings,
)
from mbgw.master.server_forward import ServerForward
from mbgw.master.table_slave import TableSlave
from mbgw.master.trace import MasterTracer
from mbgw.ops.counters import MasterCounters, TableSlaveCounters
from mbgw.ops.device_stats import MASTER_COUNTS, DeviceHealth, DeviceStats, HealthRule
from mbgw.ops.eventfd import drain
from mbgw.ops.exception_reply import gateway_exception
from mbgw.ops.status import line_row, settings_row
from mbgw.ops.trace import Outcome, TraceHub
from mbgw.protocol import pdu
from mbgw.routing.queue import AnswerWait

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")



def _line_settings(serial: SerialConfig) -> SerialConfig:
    """The settings that reopen the line: not slave mode's stout and nocheck, nor
    interframe-silence, read at each answer."""
    return dataclasses.replace(serial, stout_ms=0, nocheck=False, interframe_ms=0)


def build_face(line, cfg, routes: RouteMap, inboxes: dict, table,
               hub: TraceHub | None = None) -> "SerialFace":
    """An unstarted thread serving the master-mode line (a LineConfig) of a daemon with the
    settings cfg (SlaveConfig or MasterConfig): routes is the daemon's RouteMap, inboxes
    the Inbox of each target line by name, table the exchange table or None.  Raises
    SerialError when the device is there and does not open (one that is not there is waited
    for)."""
    settings = face_settings(cfg, line, routes)
    opened = open_at_start(settings.serial)
    try:
        return SerialFace(settings, opened, MasterCounters(), table, inboxes, hub)
    except BaseException:
        if opened is not None:
            opened.close()
        raise


class SerialFace(LineThread[FaceSettings]):
    def __init__(self, settings: FaceSettings, line: SerialLine | None,
                 counters: MasterCounters, table=None, inboxes: dict | None = None,
                 hub: TraceHub | None = None) -> None:
        """table: the exchange table (mbgw.table.memory.Table), None in a gateway without;
        inboxes: the target lines' Inbox by name, looked up at each request (a line not in
        it is not running: 0x0A or silence); hub: the daemon's trace hub (None: a new one,
        line serial's face makes it)."""
        super().__init__(settings, line)
        self.face = settings.name
        self._counters = counters
        self._inboxes = inboxes if inboxes is not None else {}   # the caller's, kept
        self.devices = DeviceHealth(MASTER_COUNTS, HealthRule(settings.demotion))
        self._down = self.devices.rule.down    # the addresses that are down, by address
        self.hub = hub if hub is not None else TraceHub()
        self.trace = self.hub         # .active: one attribute test on the request's path
        self.name_line(self.face)
        self.watch_raw(self.hub, answers=True)
        self._tracer = MasterTracer(self.hub.for_line(self.face))    # events name the line
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._lines = AnswerWait(self.face, self.wake_fd, lambda: self._stopping)
        self._servers = ServerForward(counters, self.devices, self.hub, self._tracer,
                                      self.wake_fd, self._reply)
        self._reply_to = b""       # the last frame for another slave: its reply may come next
        self._received_ns = 0       # when the request being answered was taken off the line
        self._empty_table_counters = TableSlaveCounters()
        self._table: TableSlave | None = None
        if table is not None:
            self._table = TableSlave(table, settings.table_functions)
            if settings.owns_table_flags:
                table.watch_down(self._down)
        self._routes: list[Hop | None] = [None] * 256
        self._use_routes(None, settings)
        self._rejected = -1     # the address of the frame a receive has just rejected
        if line is not None:
            self._attach(line)
        else:
            self._detach()

    @property
    def counters(self) -> MasterCounters:
        """The face's own counters (status, metrics)."""
        return self._counters

    @property
    def table(self):
        """The exchange table, or None."""
        return self._table.table if self._table is not None else None

    @property
    def table_counters(self) -> TableSlaveCounters:
        return self._table.counters if self._table is not None else self._empty_table_counters

    @property
    def turn_limit_s(self) -> float:
        """The longest request and the silence that ends it, the longest wait for its
        target, the longest answer."""
        cfg = self._cfg
        s = cfg.serial
        end_ms = s.ascii_timeout_ms if s.protocol == "ascii" else s.end_of_frame_us / 1000
        return ((end_ms + sum(s.rtsdelays) + cfg.longest_wait_ms + s.interframe_ms) / 1000
                + 2 * longest_frame_s(s) + TURN_MARGIN_S)

    def _attach(self, line: SerialLine) -> None:
        self._port = line.port
        self._send_adu = line.send_adu
        serial = line.cfg
        self._receive = self._receive_ascii if serial.protocol == "ascii" else self._receive_rtu
        self._gap_us = serial.end_of_frame_us
        self._interchar_us = serial.ascii_timeout_ms * 1000
        # what an answer given at once waits after the request: t3.5 (RTU; ASCII frames
        # end with CR LF, not silence), in whole ms
        self._quiet_ms = 0 if serial.protocol == "ascii" else -(-serial.t35_us // 1000)
        # the longest ASCII frame at the line's speed, plus one inter-character pause
        self._ascii_frame_ns = (native.ASCII_MAX_FRAME * serial.char_ns
                                + self._interchar_us * 1000)
        if self.table is not None and self._cfg.owns_table_flags:
            self.table.set_flags(line_down=False)

    def status(self) -> dict:
        """Its row of the status's "lines", counters and devices included (any thread)."""
        return line_row(self.face, self._cfg.serial.device, "master", self.state,
                        self._counters.snapshot(), [d.snapshot() for d in self.devices.all()],
                        settings=settings_row(LineConfig(self.face, self._cfg.serial,
                                                          mode="master")),
                        state_since=self.state_since)

    def reconfigure_line(self, line, cfg, routes: RouteMap) -> None:
        """New settings, as build_face takes them (from another thread)."""
        self.reconfigure(face_settings(cfg, line, routes))

    def connections(self) -> list[dict]:
        """The open upstream connections (from any thread)."""
        return self._servers.connections()

    def stop(self) -> None:
        self._servers.stop()
        self._stopping = True
        super().stop()

    # --- the line thread's hooks (mbgw.line.supervisor.LineThread) ---

    def _wake(self) -> None:
        os.eventfd_write(self.wake_fd, 1)

    def _detach(self) -> None:
        self._reply_to = b""
        if self.table is not None and self._cfg.owns_table_flags:
            self.table.set_flags(line_down=True)

    def _reopens(self, old: SerialConfig, new: SerialConfig) -> bool:
        return _line_settings(new) != _line_settings(old)

    def _configure(self, old: FaceSettings, reopen: bool) -> None:
        cfg = self._cfg
        self._use_routes(old, cfg)
        if self._table is not None:
            self._table.set_functions(cfg.table_functions)
            if cfg.table_address != old.table_address:
                self._table.counters.reset()     # a new slave (VPGate 8.5)
        if cfg.demotion != old.demotion:
            self.devices.set_rule(cfg.demotion)
        if reopen:
            self._reply_to = b""

    def _use_routes(self, old: FaceSettings | None, cfg: FaceSettings) -> None:
        """The servers' pools, and each address's hop."""
        self._servers.use(old, cfg)
        self._routes = build_hops(cfg, self._servers.pool, self._table is not None)

    def _turn(self) -> None:
        try:
            self._serve_next()
        except Interrupted:
            pass

    def _while_down(self, timeout_s: float) -> None:
        if select.select([self.wake_fd], [], [], timeout_s)[0]:
            drain(self.wake_fd)             # stopping, or a new configuration

    def _finish(self) -> None:
        """The thread ends: the device and the connections are released at once."""
        super()._finish()
        self._servers.close()

    def close(self) -> None:
        """After the thread has ended (or if it never started): its eventfds too."""
        self._servers.close()
        if self._line is not None:
            self._line.close()
            self._line = None
        self._lines.close()
        if self.wake_fd >= 0:
            os.close(self.wake_fd)
            self.wake_fd = -1

    # --- receiving ---

    def _serve_next(self) -> None:
        self._rejected = -1
        try:
            adu = self._receive()
        except ChecksumError:
            self._counters.crc_errors += 1
            self._rejected_for_table(checksum=True)
            return
        except (FrameError, LineTimeout):      # LineTimeout: noise, no ':' (ASCII)
            self._counters.invalid_frames += 1
            self._rejected_for_table(checksum=False)
            return
        if adu is None:
            return
        self._received_ns = time.monotonic_ns()
        if len(adu) < 2:
            self._counters.invalid_frames += 1
            if adu and (table := self._table_of(adu[0])) is not None:
                table.rejected(checksum=False)
            return
        self._route(adu)

    def _rejected_for_table(self, checksum: bool) -> None:
        """A frame rejected by the receiver: the table's when its address goes there."""
        self._reply_to = b""
        if (table := self._table_of(self._rejected)) is not None:
            table.rejected(checksum)

    def _table_of(self, address: int) -> TableSlave | None:
        """The table's serial slave when the address is routed to it."""
        hop = self._routes[address] if 0 < address < len(self._routes) else None
        return self._table if hop is not None and hop.kind == TABLE else None

    def _route(self, adu: bytes) -> None:
        address = adu[0]
        if address == pdu.BROADCAST:
            self._reply_to = b""
            self._broadcast(adu)
            return
        hop = self._routes[address]
        if hop is None:
            self._counters.other_addresses += 1
            self._reply_to = adu
            if self.trace.active:
                self._tracer.ignored(adu)
            return
        self._reply_to = b""
        if hop.kind == SERVER:
            self._servers.forward(adu, hop, self._received_ns, self._cfg.tcpto_ns,
                                  self._quiet_ms)
        elif hop.kind == LINE:
            self._to_line(adu, hop)
        else:
            assert self._table is not None
            self._table.serve(adu, self._answer_quietly,
                              self._tracer if self.trace.active else None,
                              identity=hop.kind == GATEWAY)

    def _receive_rtu(self) -> bytes | None:
        try:
            return self._port.read_request(self.wake_fd, self._reply_to, self._gap_us,
                                           self.idle_ms)
        except (ChecksumError, FrameError) as err:
            self._rejected = -1 if err.address is None else err.address
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
            return native.ascii_decode(got.frame)
        except (ChecksumError, FrameError):
            self._rejected = _ascii_address(got.frame)
            raise

    def _reply(self, adu: bytes, reply: bytes | None, code: int | None, stats: DeviceStats,
               outcome: str, quiet_ms: int = 0) -> str:
        """Answer the master: reply, else exception `code` (with `exception`), else
        nothing; the outcome with what became of the answer."""
        answer = reply if code is None else gateway_exception(
            self._cfg.exception, adu[1], code, self._counters, stats)
        if answer is None:
            return outcome
        if not self._answer(adu[0], answer, quiet_ms):
            stats.abandoned += 1
            return outcome + ", abandoned: the master moved on"
        return outcome + (f", answered 0x{code:02x}" if code is not None else "")

    # --- to a line in slave mode ---

    def _to_line(self, adu: bytes, hop: Hop) -> None:
        """Hand the request to the target line's thread and answer what it answers."""
        self._counters.requests += 1
        stats = self.devices.get(adu[0])
        stats.transactions += 1
        tracing = self.trace.active
        if tracing:
            self._tracer.request(adu, hop.label, None, None, hop.unit)
        inbox = self._inboxes.get(hop.line)
        outcome: str
        if inbox is None:
            self._counters.unreachable += 1
            stats.unreachable += 1
            reply, code, outcome = None, pdu.GATEWAY_PATH_UNAVAILABLE, Outcome.LINE_DOWN
        else:
            answered = self._lines.ask(inbox, hop.unit, adu[1:], self._received_ns,
                                       self._received_ns + hop.limit_ns, hop.cache)
            if answered is None:
                self._counters.timeouts += 1
                stats.timeouts += 1
                reply, code, outcome = None, pdu.GATEWAY_TARGET_FAILED, Outcome.TIMEOUT
            else:
                (reply, outcome), code = answered, None
                if reply is not None:
                    exception = reply[0] & pdu.EXCEPTION_FLAG and len(reply) > 1
                    if exception:
                        self._counters.device_exceptions += 1
                    stats.answered((time.monotonic_ns() - self._received_ns) / 1e6,
                                   reply[1] if exception else None)
        latency_ms = (time.monotonic_ns() - self._received_ns) / 1e6
        if reply is not None or code is not None:
            outcome = self._reply(adu, reply, code, stats, outcome)
        if tracing:
            self._tracer.outcome(adu, hop.label, None, hop.unit, reply, outcome,
                                 None if reply is None else latency_ms)

    # --- answering ---

    def _answer_quietly(self, address: int, answer) -> bool:
        """An answer given at once (the table's): after t3.5 of quiet."""
        return self._answer(address, answer, self._quiet_ms)

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
        self._send_adu(frame)
        self._counters.replies += 1
        return True

    # --- broadcasts ---

    def _broadcast(self, adu: bytes) -> None:
        """To the table and every server the face reaches (never to another line)."""
        tracer = self._tracer if self.trace.active else None
        if self._table is not None and any(hop is not None and hop.kind == TABLE
                                           for hop in self._routes):
            self._table.broadcast(adu, tracer)
        reached, total = self._servers.broadcast(adu, self._routes, self._cfg.tcpto_ns, tracer)
        self._counters.broadcasts += 1        # counted once sent: its transaction is over
        stats = self.devices.get(pdu.BROADCAST)
        stats.transactions += 1
        stats.broadcasts += 1
        if reached < total:
            log.debug("broadcast reached %d of %d servers", reached, total)
        if tracer is not None:
            tracer.outcome(adu, None, None, pdu.BROADCAST, None,
                           f"broadcast: {reached} of {total} servers", None)


def _ascii_address(frame: bytes) -> int:
    """The address of an ASCII frame (':' and two hex digits), -1 when it has none."""
    try:
        return int(frame[1:3], 16)
    except ValueError:
        return -1
