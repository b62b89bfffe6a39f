"""Opening the serial line with every setting, and putting frames on it (direction control,
echo).  Both gateway modes use it."""
import dataclasses
import errno
import logging
import os
import select
import struct
import time
from typing import TYPE_CHECKING, Protocol

from mbgw.errors import FrameError, LineTimeout, SerialError
from mbgw.line import native

if TYPE_CHECKING:      # the settings' type only: the line never reads the configuration files
    from mbgw.config.model import SerialConfig

log = logging.getLogger("mbgw.line")

ECHO_MARGIN_NS = 50_000_000     # the echo of a frame is back well within this after it ends
CRC = struct.Struct("<H")       # an RTU frame's CRC goes low byte first


TTY_READ_SIZE = 4096
_HUNG_UP = select.POLLHUP | select.POLLERR | select.POLLNVAL


def read_tty(fd: int, events: int) -> bytes:
    """What the tty fd holds now (poll() said events): b"" when nothing waits.  Raises
    SerialError when the device is gone (an error, or the hang-up poll() reported)."""
    try:
        data = os.read(fd, TTY_READ_SIZE)
    except BlockingIOError:
        return b""
    except OSError as err:
        raise SerialError(err.errno, f"read: {err.strerror}") from None
    if not data and events & _HUNG_UP:
        raise SerialError(errno.EIO, "read: the device hung up")
    return data


class LineCounters(Protocol):
    """What the line counts itself, in counters its owner keeps (mbgw.ops.counters)."""
    bytes_sent: int
    bytes_received: int
    noise_bytes: int
    echo_errors: int


@dataclasses.dataclass(slots=True)
class LineCounts:
    """LineCounters kept in fields of their own: for an owner that counts nothing more, or
    a base for one that does."""
    bytes_sent: int = 0
    bytes_received: int = 0
    noise_bytes: int = 0
    echo_errors: int = 0


class SerialLine:
    def __init__(self, cfg: "SerialConfig", counters: LineCounters | None = None) -> None:
        self.cfg = cfg
        # Line counters outlive a reopened port: the owner passes its own.
        self.counters: LineCounters = counters if counters is not None else LineCounts()
        fmt = cfg.format
        # libmodbus opens and configures the tty; what it cannot do is fixed after.
        libmodbus_parity = fmt.parity if fmt.parity in "neo" else "n"
        libmodbus_rate = cfg.baudrate if cfg.libmodbus_baudrate else 9600
        # the open raises DTR and RTS: one the settings want low is lowered at once, and so
        # is RTS where it keys an RS-485 transmitter (until a write)
        port = native.Port(cfg.device, libmodbus_rate, libmodbus_parity, fmt.data_bits,
                           fmt.stop_bits, dtr_low=cfg.dtr == "low",
                           rts_low=cfg.rts in ("low", "modem") or cfg.interface.drives_rts)
        try:
            if not cfg.libmodbus_baudrate:
                port.set_baudrate(cfg.baudrate)
            if fmt.parity in "ms":
                port.set_format(fmt.data_bits, fmt.parity, fmt.stop_bits)
            port.set_low_latency()
            self.rts_control = False
            if cfg.interface.drives_rts:
                before, after = cfg.rtsdelays
                # a 4-wire slave hears the master's pair, not its own: no echo to read back
                if port.set_rs485(before, after, cfg.interface.echo or cfg.interface.slave):
                    pass
                elif port.rts_available():
                    self.rts_control = True
                    log.info("%s has no kernel RS-485 mode: mbgw drives RTS itself",
                             cfg.device)
                else:
                    log.warning("%s has neither kernel RS-485 mode nor an RTS line: the "
                                "transceiver must switch direction by itself", cfg.device)
            self._control_lines(port, cfg)
        except BaseException:
            port.close()
            raise
        self.port = port
        self.char_ns = cfg.char_ns
        self._before_us = cfg.rtsdelays[0] * 1000
        self._after_us = cfg.rtsdelays[1] * 1000
        self._echo = cfg.interface.echo
        # RTU frames go out through libmodbus unless mbgw drives RTS or reads the echo
        # back: both need the whole frame here
        self.libmodbus_sends = not (self.rts_control or self._echo)

    def _control_lines(self, port: native.Port, cfg: "SerialConfig") -> None:
        """RS-232: DTR and RTS held high or low, RTS as push-to-talk, flow control."""
        if cfg.rts_ptt:
            if port.rts_available():
                self.rts_control = True
            else:
                log.warning("%s has no RTS line: rts modem cannot key the radio or modem",
                            cfg.device)
        dtr = None if cfg.dtr == "high" else False      # the kernel raises both on open
        rts = {"low": False, "modem": False}.get(cfg.rts)
        if (dtr is not None or rts is not None) and not port.set_modem_lines(dtr, rts):
            log.warning("%s has no modem control lines: dtr %s, rts %s not applied",
                        cfg.device, cfg.dtr, cfg.rts)
        if cfg.rts == "flow" or cfg.xonxoff == "use":
            port.set_flow(cfg.rts == "flow", cfg.xonxoff == "use")

    def retune(self, cfg: "SerialConfig") -> None:
        """The same port at cfg's baud rate and format, the rest as opened (mbgw scan)."""
        fmt = cfg.format
        self.port.set_baudrate(cfg.baudrate)
        self.port.set_format(fmt.data_bits, fmt.parity, fmt.stop_bits)
        self.cfg = cfg
        self.char_ns = cfg.char_ns

    def close(self) -> None:
        self.port.close()

    def transmit(self, wire: bytes) -> int:
        """Put one whole frame on the line; returns when its last byte will have left
        (CLOCK_MONOTONIC ns)."""
        self.port.write(wire, self.rts_control, self._before_us, self._after_us)
        return self._sent(wire)

    def transmit_rtu(self, adu: bytes) -> int:
        """transmit() for an RTU frame given without its CRC: libmodbus adds it and writes,
        when it may (libmodbus_sends)."""
        if not self.libmodbus_sends:
            return self.transmit(adu + CRC.pack(native.crc16(adu)))
        self.port.send_rtu(adu)
        return self._done(len(adu) + CRC.size)

    def send_adu(self, adu: bytes) -> int:
        """Put address + PDU on the line in its framing: transmit_rtu() or, on an ASCII
        line, transmit() of its ':' hex LRC CR LF frame."""
        if self.cfg.protocol == "ascii":
            return self.transmit(native.ascii_encode(adu))
        return self.transmit_rtu(adu)

    def sent_rtu(self, adu_length: int) -> None:
        """Count an RTU frame that libmodbus wrote (native.Port.exchange)."""
        self.counters.bytes_sent += adu_length + CRC.size

    def _done(self, length: int) -> int:
        """Count a frame of length bytes just written; when its last byte will have left."""
        self.counters.bytes_sent += length
        return time.monotonic_ns() + length * self.char_ns

    def _sent(self, wire: bytes) -> int:
        done_ns = self._done(len(wire))
        if self._echo:
            try:
                self.port.discard_echo(wire, done_ns + ECHO_MARGIN_NS)
            except (FrameError, LineTimeout):
                # a collision or a deaf receiver; the reply may still come
                self.counters.echo_errors += 1
                self.port.wait_quiet(time.monotonic_ns(), self.cfg.end_of_frame_us)
        return done_ns
