"""A scripted serial slave that shapes its replies on the wire: pauses inside a frame, echoes,
bad checksums, ASCII oddities.  For tests/component/test_serial_line.py.

usage: paced_slave.py DEVICE [--ascii] [--gap-ms MS] [--record PATH]

Prints READY once the pty is open, and nothing else on stdout.  Holding (and input) register
i holds 1000 + i; FC 06 is echoed; the vendor function 0x41 (a code whose reply length only
silence can tell) is answered with 0x41 followed by VENDOR_DATA; any other code gets
exception 01.  Broadcasts (address 0) are never answered.  Behaviour by the request's address
(any address not listed: the normal reply):

RTU (default; requests framed by length for 01..06, 0F, 10, otherwise by 3 ms of silence)
   1  normal reply
   2  the reply in two halves with --gap-ms (10) of silence between them
   3  the request echoed back byte for byte, then the normal reply
   4  the reply with a wrong CRC (its first CRC byte inverted)
   5  the reply carrying address 6, valid CRC
   6  a reply to FC 03/04 with two bytes more than the byte count says, valid CRC
   7  the request echoed back with its last byte altered (a collision), then the reply
   8  two bytes only: the address and the function code (no data, no CRC)
ASCII (--ascii; requests framed by ':' .. CR LF)
   1  normal reply, upper-case hex
   2  the reply with a wrong LRC
   3  the reply in lower-case hex
   4  ":0103" (a frame cut short), then the whole reply: the ':' restarts the frame
   5  the reply in two halves with --gap-ms of silence between them
   6  the request echoed back, --gap-ms of silence, then the reply
   7  a 605-character frame (over the 513 allowed), then the reply, in one write
   8  the reply carrying address 0x7F, then at once (one write) the reply
   9  the reply carrying address 0x7F, --gap-ms of silence, then the reply
  10  a 515-character frame (the shortest too long), then the reply, in one write
  11  ASCII_NOISE (bytes before a ':', then a frame cut short), then the reply, in one write

Every request received is written to --record as "rx <hex of the raw bytes>", one line each,
flushed at once.  The CRC and LRC are wire.py's own, independent of mbgw's.
"""
import argparse
import os
import select
import sys
import time

if __package__:     # imported by a test as tests.peers.paced_slave
    from .wire import crc16, lrc, open_pty, open_record, reply_pdu, rtu, rtu_request_length, serve
else:               # run as a script: its directory is on sys.path
    from wire import crc16, lrc, open_pty, open_record, reply_pdu, rtu, rtu_request_length, serve

VENDOR_FC = 0x41
VENDOR_DATA = bytes(range(0xA0, 0xA0 + 20))
VENDOR_REPLY = bytes((VENDOR_FC,)) + VENDOR_DATA
SILENCE_S = 0.003            # ends a request whose length the peer cannot tell
ASCII_NOISE = b"\x00\xff\r\n:01"   # noise, then a ':' that the reply's own ':' cuts short


def ascii_frame(body: bytes, lower: bool = False) -> bytes:
    text = (body + bytes((lrc(body),))).hex()
    return b":" + (text if lower else text.upper()).encode() + b"\r\n"


class Slave:
    def __init__(self, fd: int, gap_s: float, record) -> None:
        self.fd = fd
        self.gap_s = gap_s
        self.record = record

    def write(self, *parts: bytes) -> None:
        """Each part goes out at once; gap_s of silence between parts."""
        for i, part in enumerate(parts):
            if i:
                time.sleep(self.gap_s)      # shapes the wire: this is the gap under test
            view = memoryview(part)
            while view:
                select.select([], [self.fd], [])
                view = view[os.write(self.fd, view):]

    def read(self, timeout: float | None) -> bytes:
        if not select.select([self.fd], [], [], timeout)[0]:
            return b""
        data = os.read(self.fd, 1024)
        if not data:
            raise EOFError
        return data

    def log(self, raw: bytes) -> None:
        if self.record:
            self.record.write(f"rx {raw.hex(' ')}\n")

    # --- RTU ---

    def rtu_requests(self):
        buf = b""
        while True:
            want = rtu_request_length(buf)
            if want is None:        # unknown length: ends after SILENCE_S of silence
                more = self.read(SILENCE_S)
                if not more:
                    yield buf
                    buf = b""
                buf += more
            elif want and len(buf) >= want:
                yield buf[:want]
                buf = buf[want:]
            else:
                buf += self.read(None)

    def serve_rtu(self) -> None:
        for raw in self.rtu_requests():
            self.log(raw)
            if len(raw) < 4 or crc16(raw[:-2]) != raw[-2:]:
                continue
            address, pdu = raw[0], raw[1:-2]
            if address == 0:
                continue
            reply = rtu(bytes((address,)) + reply_pdu(pdu, VENDOR_FC, VENDOR_REPLY))
            if address == 2:
                half = len(reply) // 2
                self.write(reply[:half], reply[half:])
            elif address == 3:
                self.write(raw + reply)
            elif address == 4:
                self.write(reply[:-2] + bytes((reply[-2] ^ 0xFF, reply[-1])))
            elif address == 5:
                self.write(rtu(bytes((6,)) + reply[1:-2]))
            elif address == 6 and pdu[0] in (0x03, 0x04):
                self.write(rtu(reply[:-2] + b"\xEE\xEE"))
            elif address == 8:
                self.write(bytes((address, pdu[0])))
            elif address == 7:
                self.write(raw[:-1] + bytes((raw[-1] ^ 0x01,)) + reply)
            else:
                self.write(reply)

    # --- ASCII ---

    def ascii_requests(self):
        buf = b""
        while True:
            buf += self.read(None)
            while b"\r\n" in buf:
                frame, buf = buf.split(b"\r\n", 1)
                yield frame + b"\r\n"

    def serve_ascii(self) -> None:
        for raw in self.ascii_requests():
            self.log(raw)
            start = raw.rfind(b":")
            try:
                body = bytes.fromhex(raw[start + 1:-2].decode())
            except ValueError:
                continue
            if start < 0 or len(body) < 3 or lrc(body[:-1]) != body[-1]:
                continue
            address, pdu = body[0], body[1:-1]
            if address == 0:
                continue
            adu = bytes((address,)) + reply_pdu(pdu, VENDOR_FC, VENDOR_REPLY)
            reply = ascii_frame(adu)
            if address == 2:
                bad = (lrc(adu) + 1) & 0xFF
                self.write(reply[:-4] + f"{bad:02X}".encode() + b"\r\n")
            elif address == 3:
                self.write(ascii_frame(adu, lower=True))
            elif address == 4:
                self.write(b":0103" + reply)
            elif address == 5:
                half = len(reply) // 2
                self.write(reply[:half], reply[half:])
            elif address == 6:
                self.write(raw, reply)
            elif address == 7:
                self.write(ascii_frame(bytes((address,)) + bytes(299)) + reply)
            elif address == 10:
                self.write(ascii_frame(bytes((address,)) + bytes(254)) + reply)
            elif address == 11:
                self.write(ASCII_NOISE + reply)
            elif address == 8:
                self.write(ascii_frame(bytes((0x7F,)) + adu[1:]) + reply)
            elif address == 9:
                self.write(ascii_frame(bytes((0x7F,)) + adu[1:]), reply)
            else:
                self.write(reply)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("device")
    parser.add_argument("--ascii", action="store_true")
    parser.add_argument("--gap-ms", type=float, default=10.0)
    parser.add_argument("--record", default=None)
    args = parser.parse_args()
    fd = open_pty(args.device)
    record = open_record(args.record)
    slave = Slave(fd, args.gap_ms / 1000, record)
    serve(slave.serve_ascii if args.ascii else slave.serve_rtu, record,
          ends=(KeyboardInterrupt, EOFError))


if __name__ == "__main__":
    sys.exit(main())
