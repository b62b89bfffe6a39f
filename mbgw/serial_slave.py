"""Master mode's serial side: mbgw answers on the line for every serial address of the
slaveid table, as the proxy of the remote Modbus TCP servers.

One thread owns the line and the upstream connections.  It waits for a frame (no deadline;
the eventfd wakes it to stop) and:
- ignores a frame for an address outside the table, and the reply the slave it was for (if
  one is on the bus) sends next: the receiver is told to expect it (csrc/request.c);
- forwards a broadcast (address 0) with unit id 0 to every server of the table, and answers
  nothing (Serial Line V1.02, 2.1);
- forwards any other frame to its server and unit id with tcpto as the deadline, then writes
  the reply with the master's serial address.  No reply in time: 0x0B with `exception`, else
  silence; server unreachable: 0x0A, or silence.  If the master has sent something new in
  the meantime it has given up on the request, and the late answer is dropped.
A device that fails is closed, reopened with backoff, and reported once per change.
"""
import logging
import os
import select
import threading
import time

from mbgw import native, pdu
from mbgw.config import MasterConfig
from mbgw.counters import MasterCounters
from mbgw.errors import (ChecksumError, FrameError, GatewayTimeout, LineTimeout, NoRoute,
                         SerialError)
from mbgw.framing import framing_for
from mbgw.line_worker import REOPEN_FIRST_S, REOPEN_MAX_S
from mbgw.serial_port import SerialLine
from mbgw.tcp_client import Interrupted, UpstreamPool

log = logging.getLogger("mbgw.line")
wire = logging.getLogger("mbgw.wire")

IDLE_INPUT = 1      # Port.idle_wait: input is waiting
IDLE_TIMEOUT = 2    # Port.idle_wait: nothing happened


class SerialSlave(threading.Thread):
    def __init__(self, cfg: MasterConfig, line: SerialLine, counters: MasterCounters) -> None:
        super().__init__(name="mbgw-line", daemon=True)
        self._cfg = cfg
        self._table = cfg.slaveid
        self._counters = counters
        self._tcpto_ns = cfg.tcpto_ns
        self._gap_us = cfg.serial.end_of_frame_us
        self._interchar_us = cfg.serial.ascii_timeout_ms * 1000
        # the longest ASCII frame at the line's speed, plus one inter-character pause
        self._ascii_frame_ns = (native.ASCII_MAX_FRAME * cfg.serial.char_ns
                                + self._interchar_us * 1000)
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._pool = UpstreamPool(cfg.mdbport, cfg.max_connections, counters, self.wake_fd)
        self._stopping = False
        self._reply_to = b""       # the last frame for another slave: its reply may come next
        self._line: SerialLine | None = None
        self._attach(line)

    def _attach(self, line: SerialLine) -> None:
        self._line = line
        self._port = line.port
        self._framing = framing_for(line)
        self._receive = (self._receive_ascii if line.cfg.protocol == "ascii"
                         else self._receive_rtu)

    def stop(self) -> None:
        self._stopping = True
        os.eventfd_write(self.wake_fd, 1)

    def close(self) -> None:
        """After the thread has ended (or if it never started)."""
        self._pool.close()
        if self._line is not None:
            self._line.close()
            self._line = None
        os.close(self.wake_fd)

    def run(self) -> None:
        while not self._stopping:
            if self._line is None:
                self._reopen()
                continue
            try:
                self._serve_next()
            except Interrupted:
                pass
            except SerialError as err:
                self._lost(err)
            except Exception:   # a bug must cost one transaction, never the line
                log.exception("internal error")

    # --- receiving ---

    def _serve_next(self) -> None:
        try:
            adu = self._receive()
        except ChecksumError:
            self._counters.crc_errors += 1
            self._reply_to = b""
            return
        except (FrameError, LineTimeout):      # LineTimeout: noise, no ':' (ASCII)
            self._counters.invalid_frames += 1
            self._reply_to = b""
            return
        if adu is None:
            return
        if len(adu) < 2:
            self._counters.invalid_frames += 1
            return
        address = adu[0]
        if address == pdu.BROADCAST:
            self._reply_to = b""
            self._broadcast(adu)
            return
        route = self._table.route(address)
        if route is None:
            self._counters.other_addresses += 1
            self._reply_to = adu
            return
        self._reply_to = b""
        self._forward(adu, *route)

    def _receive_rtu(self) -> bytes | None:
        return self._port.read_request(self.wake_fd, self._reply_to, self._gap_us)

    def _receive_ascii(self) -> bytes | None:
        if self._port.idle_wait(self.wake_fd, -1) != IDLE_INPUT:
            return None
        frame = self._port.read_ascii(time.monotonic_ns() + self._ascii_frame_ns,
                                      self._interchar_us)
        return native.ascii_decode(frame)

    # --- forwarding ---

    def _forward(self, adu: bytes, host: str, unit: int) -> None:
        self._counters.requests += 1
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("line rx %s -> %s unit %d", adu.hex(" "), host, unit)
        deadline = time.monotonic_ns() + self._tcpto_ns
        try:
            reply = self._pool.transact(host, unit, adu[1:], deadline)
        except GatewayTimeout:
            self._counters.timeouts += 1
            reply = self._failure(adu[1], pdu.GATEWAY_TARGET_FAILED)
        except NoRoute:
            self._counters.unreachable += 1
            reply = self._failure(adu[1], pdu.GATEWAY_PATH_UNAVAILABLE)
        else:
            if reply[0] & pdu.EXCEPTION_FLAG:
                self._counters.device_exceptions += 1
        if reply is None:
            return
        if self._port.idle_wait(self.wake_fd, 0) != IDLE_TIMEOUT:
            self._counters.abandoned += 1       # the master moved on (or we are stopping)
            return
        answer = bytes((adu[0],)) + reply
        if wire.isEnabledFor(logging.DEBUG):
            wire.debug("line tx %s", answer.hex(" "))
        self._framing.send(answer)
        self._counters.replies += 1

    def _failure(self, function: int, code: int) -> bytes | None:
        if not self._cfg.exception:
            return None
        self._counters.gateway_exceptions += 1
        return pdu.exception_pdu(function, code)

    def _broadcast(self, adu: bytes) -> None:
        self._counters.broadcasts += 1
        deadline = time.monotonic_ns() + self._tcpto_ns
        reached = self._pool.send_all(self._table.destinations, pdu.BROADCAST, adu[1:],
                                      deadline)
        if reached < len(self._table.destinations):
            log.debug("broadcast reached %d of %d servers", reached,
                      len(self._table.destinations))

    # --- the device ---

    def _lost(self, err: SerialError) -> None:
        log.error("serial device %s lost: %s; reopening", self._cfg.serial.device, err.strerror)
        self._line.close()
        self._line = None
        self._reply_to = b""

    def _reopen(self) -> None:
        delay = REOPEN_FIRST_S
        while not self._stopping:
            if select.select([self.wake_fd], [], [], delay)[0]:
                return                          # stopping
            try:
                line = SerialLine(self._cfg.serial)
            except SerialError as err:
                log.debug("reopen failed: %s", err)
                delay = min(delay * 2, REOPEN_MAX_S)
                continue
            self._attach(line)
            log.info("serial device %s is back", self._cfg.serial.device)
            return
