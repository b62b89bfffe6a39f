"""Modbus TCP framing (Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3)."""
import struct

from mbgw.errors import BadHeader

HEADER = struct.Struct(">HHHB")     # transaction id, protocol id, length, unit id
HEADER_LEN = HEADER.size
MIN_LENGTH = 2                      # unit id + function code
MAX_LENGTH = 254                    # unit id + the largest PDU (253 bytes)


def split_frames(buf: bytearray):
    """Yield (tid, unit, pdu) for every complete frame at the start of buf and remove them.
    Raises BadHeader on a protocol id other than 0 or a length outside 2..254."""
    while len(buf) >= HEADER_LEN:
        tid, protocol, length, unit = HEADER.unpack_from(buf)
        if protocol != 0:
            raise BadHeader(f"protocol id {protocol}")
        if not MIN_LENGTH <= length <= MAX_LENGTH:
            raise BadHeader(f"length {length}")
        end = 6 + length
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
    return protocol != 0 or not MIN_LENGTH <= length <= MAX_LENGTH or len(buf) >= 6 + length


def frame(tid: int, unit: int, pdu: bytes) -> bytes:
    return HEADER.pack(tid, 0, len(pdu) + 1, unit) + pdu
