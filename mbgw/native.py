"""The only importer of the generated cffi module: typed wrappers over libmodbus and csrc/.

Every blocking call here releases the GIL (cffi API mode), so the serial line's thread
never stalls the asyncio thread.
"""
import errno
import os

from mbgw._ffi import ffi, lib
from mbgw.errors import ChecksumError, FrameError, LineTimeout, SerialError

LEN_UNKNOWN = lib.MBGW_LEN_UNKNOWN
RTU_MAX_ADU = lib.MBGW_RTU_MAX_ADU

_LIBMODBUS_ERRORS = {
    lib.EMBBADCRC: "invalid CRC",
    lib.EMBBADDATA: "invalid data",
}


def crc16(data: bytes) -> int:
    return lib.mbgw_crc16(data, len(data))


def rtu_reply_length(request_len: int, reply: bytes) -> int:
    return lib.mbgw_rtu_reply_length(request_len, reply, len(reply))


def rtu_request_length(request: bytes) -> int:
    return lib.mbgw_rtu_request_length(request, len(request))


def _strerror(code: int) -> str:
    return _LIBMODBUS_ERRORS.get(code) or os.strerror(code)


class Port:
    """One serial line, opened and configured by libmodbus, claimed for this process."""

    def __init__(self, device: str, baudrate: int, parity: str, data_bits: int, stop_bits: int):
        self.device = device
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
            self.close()
            reason = "in use by another program" if rc == -errno.EBUSY else os.strerror(-rc)
            raise SerialError(-rc, f"cannot open {device}: {reason}")
        # The response timeout then bounds the whole reply, not just its first byte.
        lib.modbus_set_byte_timeout(ctx, 0, 0)
        self._buf = ffi.new("uint8_t[]", RTU_MAX_ADU + 4)
        self._end_ns = ffi.new("int64_t *")

    def close(self) -> None:
        if self._ctx is not None:
            lib.modbus_close(self._ctx)
            lib.modbus_free(self._ctx)
            self._ctx = None
            self.fd = -1

    def _fail(self, code: int, action: str):
        if code == errno.ETIMEDOUT:
            return LineTimeout()
        if code == lib.EMBBADCRC:
            return ChecksumError()
        if code == lib.EMBBADDATA:
            return FrameError(_strerror(code))
        return SerialError(code, f"{self.device}: {action}: {_strerror(code)}")

    def send(self, adu: bytes) -> None:
        """Send address + PDU; libmodbus appends the CRC."""
        if lib.modbus_send_raw_request(self._ctx, adu, len(adu)) < 0:
            raise self._fail(ffi.errno, "write")

    def receive_confirmation(self, address: int, timeout_us: int) -> bytes | None:
        """libmodbus's receive for the codes it frames right.  None: a frame from another
        address (libmodbus ignores it and returns at once)."""
        lib.modbus_set_slave(self._ctx, address)
        lib.modbus_set_response_timeout(self._ctx, timeout_us // 1_000_000, timeout_us % 1_000_000)
        n = lib.modbus_receive_confirmation(self._ctx, self._buf)
        if n < 0:
            raise self._fail(ffi.errno, "read")
        if n == 0:
            return None
        return ffi.buffer(self._buf, n)[:]

    def read_reply(self, request_len: int, deadline_ns: int, gap_us: int,
                   by_silence: bool) -> bytes:
        """Our own receive: framed by length where known, else by gap_us of silence."""
        n = lib.mbgw_read_reply(self.fd, self._buf, RTU_MAX_ADU + 4, request_len,
                                deadline_ns, gap_us, by_silence, self._end_ns)
        if n < 0:
            raise self._fail(-n, "read")
        return ffi.buffer(self._buf, n)[:]

    @property
    def last_byte_ns(self) -> int:
        """When the last byte of the latest read_reply arrived (CLOCK_MONOTONIC)."""
        return self._end_ns[0]

    def wait_quiet(self, since_ns: int, quiet_us: int) -> int:
        """Wait until the line has been quiet for quiet_us; returns the bytes discarded."""
        n = lib.mbgw_wait_quiet(self.fd, since_ns, quiet_us)
        if n < 0:
            raise self._fail(-n, "read")
        return n

    def idle_wait(self, wake_fd: int, timeout_ms: int) -> int:
        """0 woken through wake_fd, 1 unsolicited input, 2 timed out."""
        rc = lib.mbgw_idle_wait(self.fd, wake_fd, timeout_ms)
        if rc < 0:
            raise self._fail(-rc, "poll")
        return rc
