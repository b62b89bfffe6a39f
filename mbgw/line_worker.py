"""The serial line's one owner, and the reader and writer of slave mode's TCP connections:
a thread that reads the clients' requests, takes jobs from the scheduler, runs them on the
line and delivers each outcome.  It also keeps the port alive: a device that fails is closed,
reopened with backoff, and reported once per change of state."""
import errno
import logging
import math
import threading
import time

from mbgw import mbap, pdu
from mbgw.config import SlaveConfig
from mbgw.connections import Connections
from mbgw.counters import Counters
from mbgw.device_stats import DeviceTable
from mbgw.errors import LineTimeout, SerialError
from mbgw.framing import NO_FORWARD, framing_for
from mbgw.native import ASCII_MAX_FRAME, RTU_MAX_ADU, line_thread_init, name_thread
from mbgw.scheduler import (OUTCOME_BROADCAST, OUTCOME_ERROR, OUTCOME_EXCEPTION,
                            OUTCOME_LINE_DOWN, OUTCOME_REPLY, OUTCOME_TIMEOUT, Job, Scheduler)
from mbgw.serial_master import SerialMaster
from mbgw.serial_port import SerialLine
from mbgw.tcp_connection import Client

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")

REOPEN_FIRST_S = 0.5
# Serial settings that need the port opened again; the others apply to the next transaction.
REOPEN_SETTINGS = ("device", "baudrate", "format", "interface", "rtsdelays")
REOPEN_MAX_S = 5.0
# What the watchdog (mbgw.daemon.tell_systemd) allows a turn of a line thread's loop on top
# of what the line's settings say it may take: the thread's own time, scheduling delays.
TURN_MARGIN_S = 1.0


def longest_frame_s(serial) -> float:
    """The time the longest frame of the line's protocol takes on the wire."""
    chars = ASCII_MAX_FRAME if serial.protocol == "ascii" else RTU_MAX_ADU
    return chars * serial.char_ns / 1e9


def idle_wait_ms(wait_ms: int, idle_ms: int) -> int:
    """wait_ms (-1: no limit), no longer than idle_ms (-1: no limit)."""
    if idle_ms < 0:
        return wait_ms
    return idle_ms if wait_ms < 0 else min(wait_ms, idle_ms)


class LineWorker(threading.Thread):
    def __init__(self, cfg: SlaveConfig, line: SerialLine, scheduler: Scheduler,
                 server, counters: Counters, devices: DeviceTable) -> None:
        super().__init__(name="mbgw-line", daemon=True)
        self._cfg = cfg
        self._scheduler = scheduler
        self._server = server          # the TcpServer
        self._connections: Connections = server.connections
        self._counters = counters
        self.devices = devices
        self._deliver = server.finished    # deliver(job, reply_pdu_or_None[, bytes forwarded])
        self._taken: Job | None = None     # put on the line by the shortcut, books to keep
        self._shortcut = False
        self._stopping = False
        self._new_cfg: SlaveConfig | None = None
        self._serving: Job | None = None     # until its outcome has been delivered
        self.reconfigured = False
        self._master: SerialMaster | None = self._master_on(line)
        self.up = True                 # False while the port is down: requests are refused
        # For systemd's watchdog: the monotonic time the loop last turned, and the longest
        # the thread may sleep while nothing happens (-1: no limit; set before start()).
        self.heartbeat = time.monotonic()
        self.idle_ms = -1

    @property
    def turn_limit_s(self) -> float:
        """The longest one turn of the loop takes while all is well: a transaction with its
        retries (each a quiet line, the longest request, stout, the longest reply's end)
        and the pause after a broadcast."""
        cfg = self._cfg
        s = cfg.serial
        quiet_ms = max(s.t35_us / 1000, s.silence_ms) + sum(s.rtsdelays)
        attempt_s = (quiet_ms + s.stout_ms) / 1000 + 2 * longest_frame_s(s)
        return (cfg.retries + 1) * attempt_s + cfg.turnaround_ms / 1000 + TURN_MARGIN_S

    def _master_on(self, line: SerialLine, previous: SerialMaster | None = None) -> SerialMaster:
        cfg = self._cfg
        master = SerialMaster(framing_for(line), cfg.serial, self._counters, self.devices,
                              cfg.retries, cfg.turnaround_ms)
        master.on_reply = self._reply_now
        # The shortcut takes plain RTU requests, which libmodbus sends and frames.
        self._shortcut = cfg.serial.protocol == "rtu" and line.libmodbus_sends and \
            not cfg.serial.nocheck
        if self._shortcut:
            line.port.shortcut_rules(pdu.LIBMODBUS_FRAMED, line.char_ns,
                                     cfg.serial.stout_ms * 1_000_000, cfg.slaveid)
        if previous is not None:
            master.keep_line_state(previous)
        return master

    def stop(self) -> None:
        self._stopping = True
        self._scheduler.wake()

    def reconfigure(self, cfg: SlaveConfig) -> None:
        """Use cfg from the next transaction on (called from another thread)."""
        self._new_cfg = cfg
        self._scheduler.wake()

    def _apply_new_cfg(self) -> None:
        cfg, self._new_cfg = self._new_cfg, None
        old = self._cfg.serial
        reopen = any(getattr(cfg.serial, name) != getattr(old, name)
                     for name in REOPEN_SETTINGS)
        self._cfg = cfg
        if self._master is None:
            return                                  # the reopen loop uses the new cfg
        if reopen:
            self.up = False
            self.reconfigured = True
            self._master.framing.line.close()
            self._master = None
            log.info("serial line settings changed: reopening %s", cfg.serial.device)
        else:
            self._master = self._master_on(self._master.framing.line, self._master)

    def run(self) -> None:
        line_thread_init()
        name_thread(self.name)
        while not self._stopping:
            self.heartbeat = time.monotonic()
            if self._new_cfg is not None:
                self._apply_new_cfg()
            if self._master is None:
                self._reopen()
                continue
            job = self._scheduler.take()
            if job is None:
                self._idle()
                job, self._taken = self._taken, None
                if job is not None:
                    self._serve(job, taken=True)
            else:
                self._serve(job)
                self._connections.wait(0)      # what the clients sent meanwhile
        self._connections.close_all()
        if self._master is not None:
            self._master.framing.line.close()

    def _serve(self, job: Job, taken: bool = False) -> None:
        self._serving = job
        try:
            client = job.client
            # The reply may go straight to a client whose earlier replies have all gone out.
            # With no other request waiting for the line, that client (often woken onto this
            # CPU) then runs before our bookkeeping.
            forward = NO_FORWARD if client.output_waiting or client.closed else \
                (client.fd, job.tid, job.unit, not self._scheduler.depth, client.flight)
            reply = self._master.transact(job.adu, forward, taken)
            if reply is None:
                job.outcome = OUTCOME_BROADCAST    # a reply went out through _reply_now
        except LineTimeout:
            job.outcome = OUTCOME_TIMEOUT
            reply = self._failure(job, pdu.GATEWAY_TARGET_FAILED)
        except SerialError as err:
            self._lost(err)
            job.outcome = OUTCOME_LINE_DOWN
            reply = self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE)
        except Exception:   # a bug must cost one transaction, never the line
            log.exception("internal error serving %s", job.adu.hex(" "))
            job.outcome = OUTCOME_ERROR
            reply = self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE)
        if self._serving is not None:
            self._serving = None
            try:
                self._deliver(job, reply)
            except Exception:
                log.exception("internal error delivering the outcome of %s", job.adu.hex(" "))

    def _reply_now(self, reply: bytes, sent: int) -> None:
        """The serial master found the reply (sent: the bytes of it already forwarded, or
        -1): it goes to the client before the books."""
        job, self._serving = self._serving, None
        job.outcome = OUTCOME_EXCEPTION if reply[0] & pdu.EXCEPTION_FLAG else OUTCOME_REPLY
        self._deliver(job, reply, sent)

    def _failure(self, job: Job, code: int) -> bytes | None:
        if not self._cfg.exception or job.adu[0] == pdu.BROADCAST:
            return None
        self._counters.gateway_exceptions += 1
        self.devices.get(job.adu[0]).gateway_exception(code)
        return pdu.exception_pdu(job.adu[1], code)

    def _idle(self) -> None:
        """Wait for a request, new settings or stopping; count input nobody asked for."""
        port = self._master.framing.port
        take = self._take if self._shortcut and not self._server.trace.active and \
            not wire.isEnabledFor(logging.DEBUG) else None
        try:
            if self._connections.wait(self.idle_ms, port.fd, take):
                # one frame without a request: whatever comes until the line is quiet again
                unsolicited = port.wait_quiet(time.monotonic_ns(), self._cfg.serial.t35_us)
                self._counters.unsolicited_frames += 1
                self._counters.unsolicited_bytes += unsolicited
                self._counters.bytes_received += unsolicited
        except SerialError as err:
            self._lost(err)

    def _take(self, client: Client) -> list | None:
        """The shortcut for a request that finds the line idle: C reads the client and, when
        what came is one request it can put on the line as it is, exchanges it at once and
        forwards the reply; the books are kept after (self._taken).  Anything else read is
        the client's to frame.  Returns what Client.receive would."""
        master = self._master
        port = master.framing.port
        client.in_flight += 1          # from now on, never an idle connection to evict
        n, taken = port.take_request(client.fd, master.quiet_until_ns, client.flight)
        if not taken:
            client.in_flight -= 1
            if n == -errno.EAGAIN:
                return []
            return client.received(port.taken_input[:n]) if n > 0 else None
        data = port.taken_input[:n]
        tid, _, _, unit = mbap.HEADER.unpack_from(data)
        client.last_active = time.monotonic()
        try:
            self._taken = self._server.taken(client, tid, unit, data[mbap.HEADER_LEN:])
        except Exception:   # a bug must cost one transaction, never the line
            log.exception("internal error on a request the shortcut took: %s", data.hex(" "))
        if self._taken is None and port.taken_sent < 0:
            client.in_flight -= 1      # not counted answered by a reply's forward either
        return []

    def _lost(self, err: SerialError) -> None:
        log.error("serial device %s lost: %s; reopening", self._cfg.serial.device, err.strerror)
        self.up = False
        self._master.framing.line.close()
        self._master = None

    def _reopen(self) -> None:
        delay = REOPEN_FIRST_S
        # a lost device gets a pause first, new settings are applied at once
        next_try = time.monotonic() + (0 if self.reconfigured else delay)
        self.reconfigured = False
        while not self._stopping and self._new_cfg is None:
            self.heartbeat = time.monotonic()
            self._reject_waiting()
            left = next_try - time.monotonic()
            if left > 0:
                # clients are refused meanwhile
                self._connections.wait(idle_wait_ms(math.ceil(left * 1000), self.idle_ms))
                continue
            try:
                line = SerialLine(self._cfg.serial, self._counters)
            except SerialError as err:
                log.debug("reopen failed: %s", err)
                delay = min(delay * 2, REOPEN_MAX_S)
                next_try = time.monotonic() + delay
                continue
            self._master = self._master_on(line)
            self.up = True
            log.info("serial device %s is back", self._cfg.serial.device)
            return

    def _reject_waiting(self) -> None:
        """While the port is down, nothing waits: every queued request is refused at once."""
        while (job := self._scheduler.take()) is not None:
            self._counters.line_down_rejects += 1
            job.outcome = OUTCOME_LINE_DOWN
            self._deliver(job, self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE))
