"""The frame rules of the C core, with no I/O: CRC and LRC, RTU frame lengths by function code,
ASCII encoding, and whether a reply answers its request (both modes)."""
import errno
import os

from mbgw._ffi import ffi, lib
from mbgw.errors import ChecksumError, FrameError

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


_ascii_out = ffi.new("uint8_t[]", ASCII_MAX_FRAME)
_ascii_in = ffi.new("uint8_t[]", RTU_MAX_ADU)


def ascii_encode(adu: bytes) -> bytes:
    """address..data as an ASCII frame ':' HEX LRC CR LF (not thread-safe: one line thread)."""
    n = lib.mbgw_ascii_encode(adu, len(adu), _ascii_out, ASCII_MAX_FRAME)
    if n < 0:
        raise FrameError(os.strerror(-n))
    return ffi.buffer(_ascii_out, n)[:]


def ascii_decode(frame: bytes) -> bytes:
    """An ASCII frame back to address..data.  ChecksumError on a wrong LRC."""
    n = lib.mbgw_ascii_decode(frame, len(frame), _ascii_in, RTU_MAX_ADU)
    if n == -errno.EILSEQ:
        raise ChecksumError()
    if n < 0:
        raise FrameError(os.strerror(-n))
    return ffi.buffer(_ascii_in, n)[:]


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
