"""Writes the seeds of fuzz/corpus/TARGET/ from the published request/reply pairs of
tests/vectors/pdu_pairs.txt (Modbus Application Protocol V1.1b3's examples), each in the
input layout its harness reads (see the comment at the top of fuzz/TARGET.c).  Run once when
the vectors or a layout change: python3 fuzz/seeds.py"""
import struct
from pathlib import Path

HERE = Path(__file__).resolve().parent
VECTORS = HERE.parent / "tests" / "vectors" / "pdu_pairs.txt"
ADDRESS = 0x11


def crc16(data: bytes) -> bytes:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return struct.pack("<H", crc)


def rtu(pdu: bytes) -> bytes:
    adu = bytes([ADDRESS]) + pdu
    return adu + crc16(adu)


def mbap(tid: int, pdu: bytes, protocol: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1, ADDRESS) + pdu


def pairs():
    for line in VECTORS.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            label, request, response, _ = (part.strip() for part in line.split("|", 3))
            label = label.replace("/", "-")
            yield label, bytes.fromhex(request), bytes.fromhex(response)


def seeds():
    for label, req, rsp in pairs():
        adu = bytes([ADDRESS]) + req
        yield "rtu", f"{label}-request", bytes([len(adu) - 2]) + rtu(req)
        yield "rtu", f"{label}-reply", bytes([len(adu) - 2]) + rtu(rsp)
        if 2 <= len(adu) <= 65:
            head = bytes([len(adu) - 2]) + adu + bytes([ADDRESS])
            yield "match", f"{label}-reply", head + rtu(rsp)
            yield "match", f"{label}-noise", head + b"\x00" + rtu(rsp)
            yield "match", f"{label}-exception", head + rtu(bytes([req[0] | 0x80, 2]))
        yield "request", f"{label}-request", b"\x00\x00" + rtu(req)
        if len(adu) <= 7:
            yield "request", f"{label}-other-slave", \
                b"\x00" + bytes([len(adu)]) + adu + rtu(req) + rtu(rsp)
        yield "request", f"{label}-noise-gap", b"\x01\x01\x00" + b"\xff" + rtu(req)
        yield "table", f"{label}-pdu", b"\x00" + req
        yield "table", f"{label}-mbap", b"\x02" + struct.pack(">HHHB", 1, 0, len(req) + 1, 1) + req
        yield "table", f"{label}-stale", b"\x04" + req
        if 2 <= len(adu) <= 65:
            head = bytes([len(adu) - 2]) + adu + struct.pack(">HB", 7, 3)
            yield "stream", f"{label}-reply", head + mbap(7, rsp)
            yield "stream", f"{label}-stray-first", head + mbap(6, rsp) + mbap(7, rsp)
            yield "stream", f"{label}-exception", head + mbap(7, bytes([req[0] | 0x80, 2]))
            yield "stream", f"{label}-protocol-1", head + mbap(7, rsp, protocol=1)
        if len(req) <= 253:
            frame = struct.pack(">HHHB", 9, 0, len(req) + 1, 40) + req
            yield "take", f"{label}-taken", b"\x28\x01\x00" + frame
            yield "take", f"{label}-down", b"\x28\x01\x01" + frame
            yield "take", f"{label}-two", b"\x28\x01\x00" + frame + frame


def main() -> None:
    for target, name, data in seeds():
        directory = HERE / "corpus" / target
        directory.mkdir(parents=True, exist_ok=True)
        (directory / name).write_bytes(data)


if __name__ == "__main__":
    main()
