"""What the scripted serial slaves (fault_slave.py, paced_slave.py) share: the checksums, RTU
request framing, the register contents they serve, and opening their end of the pty.

The peers run as scripts (python tests/peers/x.py, so this directory is on sys.path and they
`from wire import ...`); a test that imports a peer as tests.peers.x gets `from .wire import`.
The CRC here is our own table-driven CRC-16/MODBUS and the LRC our own sum, independent of
mbgw's (and of the tests' bit-by-bit CRC in tests/modbus.py).
"""
import os
import termios
import tty


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_TABLE = _crc_table()


def crc16(data: bytes) -> bytes:
    """CRC-16/MODBUS of data, as the two bytes sent on the wire (low byte first)."""
    crc = 0xFFFF
    for b in data:
        crc = (crc >> 8) ^ _TABLE[(crc ^ b) & 0xFF]
    return bytes((crc & 0xFF, crc >> 8))


def lrc(data: bytes) -> int:
    return -sum(data) & 0xFF


# Published vectors: Modbus over Serial Line V1.02 (11 03 00 6B 00 03: CRC 76 87, LRC 7E)
assert crc16(bytes.fromhex("11 03 00 6B 00 03")) == bytes.fromhex("76 87")
assert crc16(bytes.fromhex("01 03 00 00 00 01")) == bytes.fromhex("84 0A")
assert lrc(bytes.fromhex("11 03 00 6B 00 03")) == 0x7E


def rtu(body: bytes) -> bytes:
    """An RTU frame: body (address and PDU) and its CRC."""
    return body + crc16(body)


def rtu_request_length(buf: bytes) -> int | None:
    """Total ADU length (CRC included) of an RTU request of a public function code whose
    length the spec fixes, 0 when more bytes are needed, None if unknown."""
    if len(buf) < 2:
        return 0
    fc = buf[1]
    if fc in (0x01, 0x02, 0x03, 0x04, 0x05, 0x06):
        return 8
    if fc in (0x0F, 0x10):
        return 0 if len(buf) < 7 else 9 + buf[6]
    return None


def reply_pdu(pdu: bytes, vendor_fc: int, vendor_reply: bytes) -> bytes:
    """The reply PDU of a well-behaved slave whose holding (and input) register i holds
    1000 + i: FC03/04 the registers, FC06 the echo, vendor_fc vendor_reply, anything else
    exception 01."""
    fc = pdu[0]
    if fc in (0x03, 0x04) and len(pdu) == 5:
        start = int.from_bytes(pdu[1:3], "big")
        count = int.from_bytes(pdu[3:5], "big")
        data = b"".join((1000 + start + i).to_bytes(2, "big") for i in range(count))
        return bytes((fc, len(data))) + data
    if fc == 0x06 and len(pdu) == 5:
        return pdu
    if fc == vendor_fc:
        return vendor_reply
    return bytes((fc | 0x80, 0x01))


def open_pty(device: str) -> int:
    """The peer's end of the line: raw, non-blocking."""
    fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd, termios.TCSANOW)
    os.set_blocking(fd, False)
    return fd


def open_record(path: str | None):
    """The --record file, line-buffered (so flushed at once), or None."""
    return open(path, "w", buffering=1) if path else None


def serve(run, record, ends: tuple[type[BaseException], ...] = (KeyboardInterrupt,)) -> None:
    """Print READY (and nothing else on stdout), then run() until it returns or raises one of
    ends; the record is closed in any case."""
    print("READY", flush=True)
    try:
        run()
    except ends:
        pass
    finally:
        if record:
            record.close()
