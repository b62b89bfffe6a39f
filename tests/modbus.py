"""Modbus frames and raw Modbus TCP clients for the tests, written from the specs (Modbus
Application Protocol V1.1b3, Messaging on TCP/IP V1.0b 3.1.3, Serial Line V1.02 6.2.2),
independent of mbgw's code: the tests check mbgw's bytes against these, never against mbgw's
own.  The CRC here is computed bit by bit, independently of mbgw's and of the peers'
(tests/peers/wire.py)."""
import socket
import struct
import time

REPLY_S = 3.0               # a reply that is due never takes this long (unless told)


# ---- RTU ----

def crc16(frame: bytes) -> bytes:
    """Modbus RTU CRC (Serial Line V1.02, 6.2.2), low byte first."""
    crc = 0xFFFF
    for byte in frame:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc.to_bytes(2, "little")


# Published vector: Modbus over Serial Line V1.02, 11 03 00 6B 00 03
assert crc16(bytes.fromhex("11 03 00 6B 00 03")) == bytes.fromhex("76 87")


def rtu_frame(adu: bytes) -> bytes:
    """An RTU frame: the ADU (address and PDU) and its CRC."""
    return adu + crc16(adu)


def rtu(address: int, pdu: bytes) -> bytes:
    """The RTU frame of pdu for this address."""
    return rtu_frame(bytes((address,)) + pdu)


# ---- PDUs ----

def read_holding(start: int, count: int) -> bytes:
    return struct.pack(">BHH", 0x03, start, count)


def holding_reply(start: int, count: int) -> bytes:
    """The reply of the scripted slaves (peers/fault_slave.py, paced_slave.py): holding
    register i holds 1000 + i."""
    return bytes((0x03, 2 * count)) + b"".join(struct.pack(">H", 1000 + start + i)
                                                for i in range(count))


# ---- Modbus TCP ----

def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def recv_exact(sock: socket.socket, n: int, timeout: float = REPLY_S) -> bytes:
    """n bytes, all within timeout."""
    deadline = time.monotonic() + timeout
    data = b""
    while len(data) < n:
        sock.settimeout(max(deadline - time.monotonic(), 0.001))
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError(f"EOF after {data.hex(' ')!r}")
        data += chunk
    return data


def recv_adu(sock: socket.socket, timeout: float = REPLY_S) -> bytes:
    """One whole MBAP frame (header included)."""
    header = recv_exact(sock, 6, timeout)
    (length,) = struct.unpack(">H", header[4:6])
    return header + recv_exact(sock, length, timeout)


class Client:
    """A raw socket to the gateway on 127.0.0.1:port, frames as the test builds them."""

    def __init__(self, port: int, timeout: float = REPLY_S) -> None:
        self.timeout = timeout
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        self.tid = 0

    def send(self, *frames: bytes) -> None:
        self.sock.sendall(b"".join(frames))

    def _exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError(f"connection closed after {data.hex(' ')!r}")
            data += chunk
        return data

    def recv_raw(self, timeout: float | None = None) -> bytes | None:
        """One whole MBAP frame, or None when nothing starts arriving within timeout
        (the client's own unless given)."""
        self.sock.settimeout(self.timeout if timeout is None else timeout)
        try:
            header = self._exactly(6)
        except socket.timeout:
            return None
        self.sock.settimeout(self.timeout)
        return header + self._exactly(struct.unpack(">H", header[4:6])[0])

    def recv(self, timeout: float | None = None) -> tuple[int, int, bytes] | None:
        """(tid, unit, pdu), or None when no reply came within timeout."""
        frame = self.recv_raw(timeout)
        if frame is None:
            return None
        tid, protocol, length, unit = struct.unpack(">HHHB", frame[:7])
        assert protocol == 0 and length == len(frame) - 6, frame.hex(" ")
        return tid, unit, frame[7:]

    def ask(self, unit: int, pdu: bytes) -> bytes:
        """Send one request (the next tid) and return the reply PDU, checking the MBAP
        header."""
        self.tid += 1
        self.sock.sendall(mbap(self.tid, unit, pdu))
        header = self._exactly(7)
        tid, protocol, length, got_unit = struct.unpack(">HHHB", header)
        assert (tid, protocol, got_unit) == (self.tid, 0, unit), header.hex(" ")
        return self._exactly(length - 1)

    def close(self) -> None:
        self.sock.close()
