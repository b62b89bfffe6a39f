"""The one Python face of the C core (csrc/, through the generated cffi module, which no
other module of `line` imports): the frame rules (CRC, LRC, RTU lengths, ASCII, whether a reply
answers), the MBAP header of Modbus TCP, what C does on slave mode's client sockets (`Forward`,
`ClientReader`), and the serial port (`Port`: a libmodbus context plus csrc/'s timed reads and
writes) with what its calls hand back (`Reception`, `Take`).

Every blocking call here releases the GIL (cffi API mode), so the serial line's thread
never stalls the asyncio thread.
"""
import errno
import os
import struct
import threading
from typing import Any, NamedTuple

from mbgw._ffi import ffi, lib
from mbgw.errors import (
    BadHeader,
    ChecksumError,
    FrameError,
    LineTimeout,
    MbgwError,
    SerialError,
)

# --- frame rules, no I/O (csrc/crc.c, ascii.c, rtu.c, match.c) ---

LEN_UNKNOWN = lib.MBGW_LEN_UNKNOWN
RTU_MAX_ADU = lib.MBGW_RTU_MAX_ADU
ASCII_MAX_FRAME = lib.MBGW_ASCII_MAX_FRAME


def crc16(data: bytes) -> int:
    return lib.mbgw_crc16(data, len(data))


def lrc(data: bytes) -> int:
    return lib.mbgw_lrc(data, len(data))


def rtu_reply_length(request_len: int, reply: bytes) -> int:
    return lib.mbgw_rtu_reply_length(request_len, reply, len(reply))


def rtu_request_length(request: bytes) -> int:
    return lib.mbgw_rtu_request_length(request, len(request))


def rtu_request_end(data: bytes) -> int:
    """Where the RTU request data begins with ends, in a stream (RTU over TCP: a frame ends
    by its length and CRC, never by silence): its length once whole with a good CRC, minus
    the bytes to drop once they make no good request (a bad CRC: the frame's length), 0
    while bytes are missing.  A function whose length no rule gives ends at the shortest
    prefix whose CRC checks."""
    have = len(data)
    length = lib.mbgw_rtu_request_length(data, have)
    if length == LEN_UNKNOWN:
        for end in range(_SHORTEST_RTU, min(have, RTU_MAX_ADU) + 1):
            if _crc_checks(data, end):
                return end
        return -have if have >= RTU_MAX_ADU else 0
    if length < 0:                          # a byte count no request has
        return -have
    if length == 0 or have < length:
        return 0
    return length if _crc_checks(data, length) else -length


_SHORTEST_RTU = 4                           # address, function, CRC


def _crc_checks(data: bytes, end: int) -> bool:
    return lib.mbgw_crc16(data, end - 2) == data[end - 2] | data[end - 1] << 8


def rtu_adu(unit: int, pdu: bytes) -> bytes:
    """An RTU frame: address, PDU, CRC."""
    adu = bytes((unit,)) + pdu
    crc = lib.mbgw_crc16(adu, len(adu))
    return adu + bytes((crc & 0xFF, crc >> 8))


class _AsciiBuffers(threading.local):
    """Each line thread's own buffers: the C calls release the GIL, so two ASCII lines (a
    serial face and a line in slave mode) would otherwise write into one."""

    def __init__(self) -> None:
        self.out = ffi.new("uint8_t[]", ASCII_MAX_FRAME)
        self.into = ffi.new("uint8_t[]", RTU_MAX_ADU)


_ascii = _AsciiBuffers()


def ascii_encode(adu: bytes) -> bytes:
    """address..data as an ASCII frame ':' HEX LRC CR LF."""
    out = _ascii.out
    n = lib.mbgw_ascii_encode(adu, len(adu), out, ASCII_MAX_FRAME)
    if n < 0:
        raise FrameError(os.strerror(-n))
    return ffi.buffer(out, n)[:]


def ascii_decode(frame: bytes) -> bytes:
    """An ASCII frame back to address..data.  ChecksumError on a wrong LRC."""
    into = _ascii.into
    n = lib.mbgw_ascii_decode(frame, len(frame), into, RTU_MAX_ADU)
    if n == -errno.EILSEQ:
        raise ChecksumError()
    if n < 0:
        raise FrameError(os.strerror(-n))
    return ffi.buffer(into, n)[:]


def reply_matches(request: bytes, reply: bytes) -> bool:
    return lib.mbgw_reply_matches(request, len(request), reply, len(reply)) == 1


REPLY_ANSWERS = lib.MBGW_REPLY_ANSWERS
REPLY_BAD_LENGTH = lib.MBGW_REPLY_BAD_LENGTH
REPLY_WRONG_UNIT = lib.MBGW_REPLY_WRONG_UNIT
REPLY_WRONG_FUNCTION = lib.MBGW_REPLY_WRONG_FUNCTION


def tcp_reply_verdict(request: bytes, unit: int, reply_unit: int, reply: bytes) -> int:
    """Master mode: what a server's reply PDU (and its unit id) is to the request PDU sent
    to unit: one of REPLY_*."""
    return lib.mbgw_tcp_reply_verdict(request, len(request), unit, reply_unit, reply,
                                      len(reply))


# --- Modbus TCP framing (Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3): which
# headers frame something is csrc/mbap.c's rule, the one csrc/forward.c's shortcut and
# csrc/table_answer.c apply too ---

HEADER = struct.Struct(">HHHB")     # transaction id, protocol id, length, unit id
HEADER_LEN = HEADER.size

# frame_length(protocol id, length field): the frame's length, header included (6 + the
# length field), or -errno for a header that frames nothing (bad_header).  The C function
# itself: it runs for every frame read.
frame_length = lib.mbgw_mbap_frame_len


def bad_header(code: int, protocol: int, length: int) -> BadHeader:
    """What frame_length's -errno code says of a header."""
    return BadHeader(f"protocol id {protocol}" if code == -errno.EPROTO else f"length {length}")


def split_frames(buf: bytearray):
    """Yield (tid, unit, pdu) for every complete frame at the start of buf and remove them.
    Raises BadHeader on a protocol id other than 0 or a length outside 2..254."""
    while len(buf) >= HEADER_LEN:
        tid, protocol, length, unit = HEADER.unpack_from(buf)
        end = frame_length(protocol, length)
        if end < 0:
            raise bad_header(end, protocol, length)
        if len(buf) < end:
            return
        pdu = bytes(buf[HEADER_LEN:end])
        del buf[:end]
        yield tid, unit, pdu


def whole_frame(buf: bytearray) -> bool:
    """Whether buf begins with a whole frame (or a bad header, which split_frames raises)."""
    if len(buf) < HEADER_LEN:
        return False
    _, protocol, length, _ = HEADER.unpack_from(buf)
    end = frame_length(protocol, length)
    return end < 0 or len(buf) >= end


def frame(tid: int, unit: int, pdu: bytes) -> bytes:
    return HEADER.pack(tid, 0, len(pdu) + 1, unit) + pdu


# --- slave mode's client sockets (csrc/forward.c): where a reply goes straight from the
# line, a counter C counts down as it hands a reply over, reads dated by the kernel ---

NO_COUNTER = ffi.NULL


class Forward(NamedTuple):
    """Where the C receive sends a reply that answers its request at once (struct
    mbgw_forward): the client's socket, as a Modbus TCP frame with the client's transaction
    and unit ids; yield_cpu: then the client woken runs first (nothing else waits for the
    line); in_flight: the client's counter(), which C counts down as it hands the reply
    over."""
    fd: int
    tid: int
    unit: int
    yield_cpu: bool
    in_flight: Any


# the reply goes nowhere before it is returned
NO_FORWARD = Forward(-1, 0, 0, False, NO_COUNTER)


def counter():
    """An int that C can count down (a client's requests in flight): c[0]."""
    return ffi.new("int *")


def stamp_arrivals(fd: int) -> None:
    """The kernel dates what arrives on socket fd (a listening socket: on each connection it
    accepts), for ClientReader.  Raises OSError."""
    err = lib.mbgw_stamp_arrivals(fd)
    if err < 0:
        raise OSError(-err, os.strerror(-err))


class ClientReader:
    """Reads a client's socket into one buffer and tells when what it read arrived: by the
    kernel's receive timestamp (stamp_arrivals), so that requests read together after a
    transaction are known in the order they came.  For one thread (the line thread)."""

    def __init__(self, size: int) -> None:
        self._size = size
        self._buf = ffi.new("uint8_t[]", size)
        self._arrived = ffi.new("int64_t *")
        self.data = memoryview(ffi.buffer(self._buf))   # read() put its bytes at the front

    def read(self, fd: int) -> int:
        """The bytes read into data, 0 at the connection's end, -EAGAIN when nothing waits,
        another -errno."""
        return lib.mbgw_client_recv(fd, self._buf, self._size, self._arrived)

    @property
    def arrived_ns(self) -> int:
        """When the newest of what read() read arrived (CLOCK_MONOTONIC); now if the kernel
        did not date it."""
        return self._arrived[0]


# --- a remote line's socket on Modbus TCP (csrc/remote.c) ---

REMOTE_SIZE = 4096      # what one exchange reads from the device's socket at most
BEFORE_UNIT = HEADER_LEN - 1     # the MBAP header's bytes before the unit id


class MbapExchange:
    """mbgw_remote_exchange on a connected socket: the request out, its reply cut, matched
    and found, in one call; what else it did is in `result` (struct mbgw_remote: sent_ns,
    end_ns, received, stale, strays, noise, left, forwarded).  And a lent client's request
    taken to the line (take, then reply_to_loan).  Its buffers are made once: one thread
    (the remote line's) uses it."""

    def __init__(self) -> None:
        self._buf = ffi.new("uint8_t[]", REMOTE_SIZE)
        self.result = ffi.new("struct mbgw_remote *")
        self.loan = ffi.new("struct mbgw_loan *")
        self._to = ffi.new("struct mbgw_forward *")

    def exchange(self, fd: int, adu: bytes, tid: int, stout_ns: int,
                 forward: Forward = NO_FORWARD) -> int:
        """Send adu (address + PDU) with transaction id tid and wait stout_ns for its reply,
        which goes to forward's client at once.  Returns the reply's length (reply() gives
        it) or -errno (mbgw_remote_exchange's: result.sent_ns is 0 when the request was not
        sent)."""
        return lib.mbgw_remote_exchange(fd, self._buf, REMOTE_SIZE, adu, len(adu), tid,
                                        stout_ns, self._forward_to(forward), self.result)

    def lend_rules(self, units, down) -> None:
        """What a lent client's request must meet (struct mbgw_loan): units, 256 bytes, the
        address each unit id has on the line (0: not the line's); down, the addresses that
        are down.  Both are read by every take: kept up to date in place."""
        loan = self.loan
        self._units = ffi.from_buffer(units)
        self._down = ffi.from_buffer(down)
        loan.units, loan.down = self._units, self._down

    def take(self, client_fd: int, in_flight, line_fd: int, tid: int) -> int:
        """mbgw_remote_take: 1 the client's request went on the line with tid (result.sent_ns
        0: it could not be sent), 0 the client's input is not for a take, -errno."""
        return lib.mbgw_remote_take(client_fd, in_flight, line_fd, self._buf, REMOTE_SIZE,
                                    tid, self.loan, self.result)

    def reply_to_loan(self, line_fd: int, tid: int, deadline_ns: int,
                      forward: Forward) -> int:
        """After take: its reply, found by deadline_ns and sent to forward's client; as
        exchange() returns."""
        loan = self.loan
        return lib.mbgw_remote_reply(line_fd, self._buf, REMOTE_SIZE, loan.adu, loan.adu_len,
                                     tid, deadline_ns, self._forward_to(forward), self.result)

    def taken_adu(self) -> bytes:
        """The request take sent: address + PDU."""
        return ffi.buffer(self.loan.adu, self.loan.adu_len)[:]

    def reply(self, length: int) -> bytes:
        """The reply exchange() found (its length): unit id + PDU."""
        return ffi.buffer(self._buf + self.result.at + BEFORE_UNIT,
                          length - BEFORE_UNIT)[:]

    def _forward_to(self, forward: Forward):
        to = self._to
        to.fd, to.tid, to.unit, to.yield_cpu, to.in_flight = forward
        return to


# --- the serial port (csrc/line.c, tty.c, request.c, forward.c, capture.c) ---

REPLY_AT = lib.MBGW_REPLY_AT
REPLY_SCAN = lib.MBGW_REPLY_SCAN
# what Port.idle_wait saw
IDLE_WOKEN = lib.MBGW_IDLE_WOKEN
IDLE_INPUT = lib.MBGW_IDLE_INPUT
IDLE_TIMEOUT = lib.MBGW_IDLE_TIMEOUT
INPUT_SIZE = 4096       # what take_request() reads from a client at most
CRC_LEN = 2
_RECORD = struct.Struct("=BqH")     # a capture record's head: direction, time, length

_LIBMODBUS_ERRORS = {
    lib.EMBBADCRC: "invalid CRC",
    lib.EMBBADDATA: "invalid data",
}


class Reception(NamedTuple):
    """What one receive on the line gave (Port.receive_reply, exchange, exchanged, read_ascii,
    read_reply).  A lost device is raised (SerialError), never returned."""
    frame: bytes | None       # the request's address + PDU (RTU: its CRC checked and removed);
    #                           None: no frame, or one from another address
    fault: MbgwError | None   # LineTimeout, ChecksumError or FrameError instead of a frame
    foreign_address: int      # the address of a frame from another address (-1: none)
    length: int               # the bytes of the frame received (the other address's too)
    noise: int                # bytes read that were in no frame
    forwarded: int            # bytes of the reply its client's socket took (-1: not sent)
    request_end_ns: int       # exchange: when the request's last byte left (0: not sent here)
    last_byte_ns: int         # when the last byte read arrived (CLOCK_MONOTONIC)
    foreign: bytes = b""      # the frame from another address (address + PDU), if one came


class Take(NamedTuple):
    """What Port.take_request read from a client, and whether it went on the line."""
    input: bytes              # what was read; b"" when nothing (or the connection ended)
    status: int               # bytes read, 0 at the connection's end, -errno
    taken: bool               # exchanged: Port.exchanged() gives its outcome
    forwarded: int            # bytes of its reply the client's socket took (-1: not sent)
    arrived_ns: int           # when what was read arrived (ClientReader.arrived_ns)


def tty_cflag(cflag: int, data_bits: int, parity: str, stop_bits: int) -> int:
    return lib.mbgw_tty_cflag(cflag, data_bits, parity.encode(), stop_bits)


def line_thread_init() -> None:
    """In the thread that owns the line, before its first transaction."""
    lib.mbgw_line_thread_init()


def name_thread(name: str) -> None:
    """The calling thread's name as ps -L and top -H show it (at most 15 bytes)."""
    lib.mbgw_name_thread(name.encode())


def _strerror(code: int) -> str:
    return _LIBMODBUS_ERRORS.get(code) or os.strerror(code)


class Port:
    """One serial line, opened and configured by libmodbus, claimed for this process."""

    def __init__(self, device: str, baudrate: int, parity: str, data_bits: int, stop_bits: int,
                 dtr_low: bool = False, rts_low: bool = False):
        """dtr_low, rts_low: the control lines lowered right after the first open, before
        libmodbus opens and configures the tty."""
        self.device = device
        self._ctx: Any = None          # libmodbus's modbus_t * while the line is open
        self._lock_fd = lib.mbgw_tty_lock(device.encode(), dtr_low, rts_low)
        if self._lock_fd < 0:
            code = -self._lock_fd
            reason = "in use by another program" if code == errno.EBUSY else os.strerror(code)
            raise SerialError(code, f"cannot open {device}: {reason}")
        try:
            self._open(device, baudrate, parity, data_bits, stop_bits)
        except BaseException:
            self.close()
            raise
        self._buf = ffi.new("uint8_t[]", max(ASCII_MAX_FRAME, REPLY_AT + REPLY_SCAN))
        self._end_ns = ffi.new("int64_t *")
        self._forwarded = ffi.new("int *")
        self._noise = ffi.new("int *")
        self._times = ffi.new("int64_t[2]")
        self._to = ffi.new("struct mbgw_forward *")
        self._shortcut = ffi.new("struct mbgw_shortcut *")
        self._framed = ffi.NULL
        self._down = ffi.NULL
        self._late_until = ffi.NULL
        self._own = ffi.NULL
        self._in = ffi.new("uint8_t[]", INPUT_SIZE)
        self.set_byte_timeout(0)

    def _open(self, device: str, baudrate: int, parity: str, data_bits: int,
              stop_bits: int) -> None:
        ctx = lib.modbus_new_rtu(device.encode(), baudrate, parity.upper().encode(),
                                 data_bits, stop_bits)
        if ctx == ffi.NULL:
            raise SerialError(ffi.errno, f"cannot use {device}: {os.strerror(ffi.errno)}")
        if lib.modbus_connect(ctx) < 0:
            code = ffi.errno
            lib.modbus_free(ctx)
            raise SerialError(code, f"cannot open {device}: {os.strerror(code)}")
        self._ctx = ctx
        self.fd = lib.modbus_get_socket(ctx)
        rc = lib.mbgw_tty_claim(self.fd)
        if rc < 0:
            raise SerialError(-rc, f"cannot open {device}: {os.strerror(-rc)}")

    def close(self) -> None:
        if self._ctx is not None:
            lib.mbgw_tty_release(self.fd)
            lib.modbus_close(self._ctx)
            lib.modbus_free(self._ctx)
            self._ctx = None
            self.fd = -1
        if self._lock_fd >= 0:
            os.close(self._lock_fd)
            self._lock_fd = -1

    def _fail(self, code: int, action: str):
        if code == errno.ETIMEDOUT:
            return LineTimeout()
        if code in (lib.EMBBADCRC, errno.EILSEQ):
            return ChecksumError()
        if code in (lib.EMBBADDATA, errno.EBADMSG, errno.EMSGSIZE, errno.EPROTO):
            return FrameError(_strerror(code))
        return SerialError(code, f"{self.device}: {action}: {_strerror(code)}")

    def error(self, code: int, action: str) -> MbgwError:
        """The exception for errno `code` of a call doing `action`."""
        return self._fail(code, action)

    def _check(self, rc: int, action: str) -> int:
        if rc < 0:
            raise self._fail(-rc, action)
        return rc

    # --- settings libmodbus cannot make ---

    def set_baudrate(self, baudrate: int) -> None:
        self._check(lib.mbgw_tty_set_baud(self.fd, baudrate), "set baud rate")

    def set_format(self, data_bits: int, parity: str, stop_bits: int) -> None:
        self._check(lib.mbgw_tty_set_format(self.fd, data_bits, parity.encode(), stop_bits),
                    "set format")

    def settings(self) -> tuple[int, int]:
        """(cflag, baud rate) as the kernel holds them."""
        cflag, baud = ffi.new("uint32_t *"), ffi.new("uint32_t *")
        self._check(lib.mbgw_tty_get(self.fd, cflag, baud), "read settings")
        return cflag[0], baud[0]

    def set_low_latency(self) -> bool:
        return lib.mbgw_tty_low_latency(self.fd) == 0

    def set_rs485(self, before_ms: int, after_ms: int, rx_during_tx: bool) -> bool:
        """Kernel RS-485 direction control; False when the driver lacks it."""
        return lib.mbgw_tty_rs485(self.fd, before_ms, after_ms, rx_during_tx) == 0

    def rts_available(self) -> bool:
        return lib.mbgw_rts_available(self.fd) == 0

    def set_modem_lines(self, dtr: bool | None, rts: bool | None) -> bool:
        """DTR and RTS high (True), low (False) or left (None); False when the tty has no
        modem control lines."""
        def level(value: bool | None) -> int:
            return -1 if value is None else int(value)
        return lib.mbgw_tty_modem_lines(self.fd, level(dtr), level(rts)) == 0

    def set_flow(self, rtscts: bool, xonxoff: bool) -> None:
        self._check(lib.mbgw_tty_flow(self.fd, rtscts, xonxoff), "set flow control")

    def set_byte_timeout(self, timeout_us: int) -> None:
        """The silence that ends a reply's frame (and a burst of noise) in receive_reply."""
        self._gap_us = timeout_us
        self._shortcut.gap_us = timeout_us

    # --- transfers ---

    def send_rtu(self, adu: bytes) -> None:
        """Send address + PDU; libmodbus appends the CRC."""
        if lib.mbgw_send_rtu(self._ctx, adu, len(adu)) < 0:
            raise self._fail(ffi.errno, "write")

    def write(self, frame: bytes, rts_control: bool = False, before_us: int = 0,
              after_us: int = 0) -> None:
        self._check(lib.mbgw_write_frame(self.fd, frame, len(frame), rts_control,
                                         before_us, after_us), "write")

    def discard_echo(self, sent: bytes, deadline_ns: int) -> None:
        self._check(lib.mbgw_discard_echo(self.fd, sent, len(sent), deadline_ns), "read echo")

    def receive_reply(self, adu: bytes, deadline_ns: int,
                      forward: Forward = NO_FORWARD) -> Reception:
        """The next frame after the request adu (csrc mbgw_find_reply: noise is skipped and
        the reply found behind it), CRC checked.  With a forward, a reply that answers adu
        in time has gone to its client already (Reception.forwarded)."""
        n = lib.mbgw_receive_reply(self._ctx, self._buf, adu, len(adu), deadline_ns,
                                   self._gap_us, self._forward_to(forward),
                                   self._end_ns, self._forwarded, self._noise)
        return self._received(n, adu[0], 0, self._end_ns[0], self._forwarded[0],
                              self._noise[0])

    def exchange(self, adu: bytes, char_ns: int, stout_ns: int,
                 forward: Forward = NO_FORWARD) -> Reception:
        """send_rtu(adu) and receive_reply() in one call, the deadline stout_ns after the
        request's last byte (char_ns a character): nothing runs between the write and the
        wait.  Raises SerialError when the write failed."""
        times = self._times
        n = lib.mbgw_exchange(self._ctx, self._buf, adu, len(adu), char_ns, stout_ns,
                              self._gap_us, self._forward_to(forward),
                              times, self._forwarded, self._noise)
        return self._exchanged(n, times, adu[0], self._forwarded[0], self._noise[0])

    def shortcut_rules(self, framed, char_ns: int, stout_ns: int, slaveid: int,
                       down: bytearray, late_until, own: bytes | bytearray = bytes(256)
                       ) -> None:
        """What take_request() needs: the function codes libmodbus frames, the line's
        character time, stout, the forced serial address (0: none), the addresses that
        are down (256 flags) and the ends of their late windows (256 int64, an array "q");
        C reads both as they are at each take, so the owner keeps them up to date, never
        resized.  own: 256 flags, the addresses with timing of their own ([[device]]),
        whose requests Python sends."""
        self._framed = ffi.new("uint8_t[256]", [code in framed for code in range(256)])
        self._down = ffi.from_buffer("uint8_t[]", down)
        self._late_until = ffi.from_buffer("int64_t[]", late_until)
        self._own = ffi.new("uint8_t[256]", bytes(own))
        sc = self._shortcut
        sc.framed = self._framed
        sc.down = self._down
        sc.late_until = self._late_until
        sc.own = self._own
        sc.char_ns = char_ns
        sc.stout_ns = stout_ns
        sc.slaveid = slaveid

    def take_request(self, client_fd: int, quiet_until_ns: int,
                     in_flight=NO_COUNTER) -> Take:
        """mbgw_take_request: read client_fd and, when what came is one request the line can
        take as it is, exchange it at once (in_flight: the client's counter()).  After a
        take, exchanged() gives the outcome."""
        sc = self._shortcut
        sc.quiet_until_ns = quiet_until_ns
        n = lib.mbgw_take_request(self._ctx, client_fd, in_flight, self._in, INPUT_SIZE,
                                  self._buf, sc)
        data = ffi.buffer(self._in, n)[:] if n > 0 else b""
        taken = bool(sc.taken)
        return Take(data, n, taken, sc.forwarded if taken else -1, sc.arrived_ns)

    def exchanged(self) -> Reception:
        """What exchange() would have returned, for the request take_request() took."""
        sc = self._shortcut
        return self._exchanged(sc.result, sc.times, sc.address, sc.forwarded, sc.noise)

    def _exchanged(self, n: int, times, address: int, forwarded: int,
                   noise: int) -> Reception:
        if n < 0 and times[0] == 0:        # the request was not written
            raise self._fail(-n, "write")
        return self._received(n, address, times[0], times[1], forwarded, noise)

    def _forward_to(self, forward: Forward):
        to = self._to
        to.fd, to.tid, to.unit, to.yield_cpu, to.in_flight = forward
        return to

    def _received(self, n: int, address: int, request_end_ns: int, last_byte_ns: int,
                  forwarded: int, noise: int) -> Reception:
        """What C received (n bytes of frame, or -errno) after a request to address."""
        if n < 0:
            fault = self._fail(-n, "read")
            if isinstance(fault, SerialError):
                raise fault
            return Reception(None, fault, -1, 0, noise, -1, request_end_ns, last_byte_ns)
        frame = ffi.buffer(self._buf + REPLY_AT, n - CRC_LEN)[:]
        if frame[0] != address:
            return Reception(None, None, frame[0], n, noise, -1, request_end_ns, last_byte_ns,
                             frame)
        return Reception(frame, None, -1, n, noise, forwarded, request_end_ns, last_byte_ns)

    def read_reply(self, deadline_ns: int, gap_us: int) -> Reception:
        """Our own RTU receive, nothing checked: framed by gap_us of silence."""
        n = lib.mbgw_read_reply(self.fd, self._buf, RTU_MAX_ADU + 4, deadline_ns, gap_us,
                                self._end_ns)
        return self._read(n, 0)

    def read_ascii(self, deadline_ns: int, interchar_us: int) -> Reception:
        """One ASCII frame, ':' to CR LF, as it came (its LRC unchecked)."""
        n = lib.mbgw_ascii_read_frame(self.fd, self._buf, ASCII_MAX_FRAME, deadline_ns,
                                      interchar_us, self._end_ns, self._noise)
        return self._read(n, self._noise[0])

    def _read(self, n: int, noise: int) -> Reception:
        if n < 0:
            fault = self._fail(-n, "read")
            if isinstance(fault, SerialError):
                raise fault
            return Reception(None, fault, -1, 0, noise, -1, 0, self._end_ns[0])
        return Reception(ffi.buffer(self._buf, n)[:], None, -1, n, noise, -1, 0,
                         self._end_ns[0])

    def wait_quiet(self, since_ns: int, quiet_us: int) -> int:
        """Wait until the line has been quiet for quiet_us; returns the bytes discarded."""
        return self._check(lib.mbgw_wait_quiet(self.fd, since_ns, quiet_us), "read")

    def idle_wait(self, wake_fd: int, timeout_ms: int) -> int:
        """0 woken through wake_fd, 1 unsolicited input, 2 timed out."""
        return self._check(lib.mbgw_idle_wait(self.fd, wake_fd, timeout_ms), "poll")

    def read_request(self, wake_fd: int, reply_to: bytes, gap_us: int,
                     idle_ms: int = -1) -> bytes | None:
        """Master mode: the next RTU frame for any address, without its (valid) CRC; None
        when woken through wake_fd, or after idle_ms (-1: no limit), before a frame began.
        reply_to: the last frame for an address we do not answer for (its slave's reply may
        come next), or b"".  Raises ChecksumError or FrameError (with the rejected frame's
        first byte: its address, unless noise), SerialError."""
        n = lib.mbgw_rtu_read_request(self.fd, wake_fd, self._buf, RTU_MAX_ADU, reply_to,
                                      len(reply_to), gap_us, idle_ms)
        if n == -errno.ECANCELED:
            return None
        if n < 0:
            fault = self._fail(-n, "read")
            if isinstance(fault, (ChecksumError, FrameError)):
                fault.address = self._buf[0]
            raise fault
        return ffi.buffer(self._buf, n - 2)[:]


class Capture:
    """The raw line monitor's buffer (csrc/capture.c): while started, C appends every byte
    the line reads or writes; take() drains it, on the line's thread."""
    SIZE = 1 << 16

    def __init__(self) -> None:
        self._buf = ffi.new("uint8_t[]", self.SIZE)
        self._c = ffi.new("struct mbgw_capture *")
        self._c.buf = self._buf
        self._c.cap = self.SIZE
        self.on = False

    def start(self) -> None:
        self._c.len = 0
        lib.mbgw_capture_set(self._c)
        self.on = True

    def stop(self) -> None:
        """On the line's thread (another thread's capture is not touched)."""
        lib.mbgw_capture_unset(self._c)
        self.on = False

    def __del__(self) -> None:
        if self.on:                    # C must not write into freed memory
            self.stop()

    def take(self) -> tuple[list[tuple[bool, int, bytes]], int]:
        """What came since the last take: (sent, time ns, bytes) in order; and the bytes
        dropped for want of room."""
        c = self._c
        data = ffi.buffer(self._buf, c.len)[:]
        dropped = c.dropped
        c.len = 0
        c.dropped = 0
        records = []
        at = 0
        while at < len(data):
            direction, t, n = _RECORD.unpack_from(data, at)
            at += _RECORD.size
            records.append((direction == lib.MBGW_CAPTURE_TX, t, data[at:at + n]))
            at += n
        return records, dropped
