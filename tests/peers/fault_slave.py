"""A scripted Modbus RTU slave for fault injection, answering by serial address.

usage: fault_slave.py DEVICE [--record PATH] [--late-ms MS] [--garbage HEX]
                      [--garbage-pause-ms MS] [--foreign-pause-ms MS] [--mute-first N]
                      [--reply-delay-ms MS] [--answer-first N] [--then-mute N]

Prints READY once the pty is open, and nothing else on stdout.  Holding (and input) register i
holds 1000 + i.  Behaviour by the request's address:

   0  broadcast: recorded, never answered
   1  normal reply (so does any address not listed)
   2  silent
   3  the reply, after --late-ms (800)
   4  the reply with a bad CRC
   5  the reply carrying address 6
   7  the reply with function 0x04 for 0x03 (0x03 for anything else)
   8  the reply from address 9, a pause (--foreign-pause-ms, 5), then the reply
  10  the one the tests use for vendor FC 108 (0x6C), answered by 0x6C + 37 bytes
  11  exception 02 (illegal data address)
  12  the reply to every second request it gets, nothing to the others
  13  --garbage (55 aa 55), a silence (--garbage-pause-ms, 20), then the reply; with
      --garbage-pause-ms 0 the garbage and the reply in one write (noise right before it)
  14  silent to its first --mute-first (3) requests, then the reply (a device that recovers)
  15  --garbage only, never the reply (noise alone)
  16  FC03/04: one register fewer than asked (a wrong quantity)
  17  a slow device: its first request answered after --late-ms, a request that comes
      meanwhile answered 5 ms after that (it was busy), later ones at once
  18  a device that stops for a while: its first --answer-first (5) requests answered after
      --reply-delay-ms (10), the next --then-mute (3) not at all, the later ones answered
      after --reply-delay-ms again

The reply: FC03/04 the registers, FC06 the echo, FC 108 the vendor reply (any address),
anything else exception 01.

Requests are framed by length for the function codes whose request length is fixed by the
spec (01..06, 0F, 10, and 0x6C sub-functions 07/08), otherwise by 3 ms of silence.  Every frame
received is written to --record as "<time.monotonic()> rx <hex>" (bad ones as "rx-bad"), and
every frame sent as "<time> tx <hex>", one line each, flushed at once.  The CRC is wire.py's
own table-driven CRC-16/MODBUS, independent of mbgw's.
"""
import argparse
import heapq
import os
import select
import sys
import time

if __package__:     # imported by a test as tests.peers.fault_slave
    from .wire import crc16, open_pty, open_record, reply_pdu, rtu, rtu_request_length, serve
else:               # run as a script: its directory is on sys.path
    from wire import crc16, open_pty, open_record, reply_pdu, rtu, rtu_request_length, serve


def adu(address: int, pdu: bytes) -> bytes:
    return rtu(bytes((address,)) + pdu)


VENDOR_FC = 0x6C
VENDOR_REPLY = bytes((VENDOR_FC,)) + bytes.fromhex("07 01 00 05") + bytes(range(0xA0, 0xA0 + 33))
assert len(VENDOR_REPLY) == 38
SILENCE_S = 0.003
BUSY_GAP_S = 0.005      # address 17: a request that came while busy, answered this after
PARTIAL_S = 0.050       # a length-known frame not completed within this is dropped


def request_length(buf: bytes) -> int | None:
    """Total ADU length (CRC included), 0 when more bytes are needed, None if unknown."""
    if len(buf) >= 2 and buf[1] == VENDOR_FC:
        if len(buf) < 3:
            return 0
        return {0x07: 7, 0x08: 8}.get(buf[2])
    return rtu_request_length(buf)


def normal_reply(address: int, pdu: bytes) -> bytes:
    """The reply PDU of a well-behaved slave."""
    return reply_pdu(pdu, VENDOR_FC, VENDOR_REPLY)


class Slave:
    def __init__(self, fd: int, record, late_s: float, garbage: bytes, garbage_pause_s: float,
                 foreign_pause_s: float, mute_first: int = 3, reply_delay_s: float = 0.010,
                 answer_first: int = 5, then_mute: int = 3) -> None:
        self.fd = fd
        self.mute_first = mute_first
        self.reply_delay_s = reply_delay_s
        self.answer_first = answer_first
        self.then_mute = then_mute
        self.garbage = garbage
        self.garbage_pause_s = garbage_pause_s
        self.foreign_pause_s = foreign_pause_s
        self.record = record
        self.late_s = late_s
        self.pending: list[tuple[float, int, bytes]] = []     # (when, seq, bytes) to write
        self.seq = 0
        self.counts: dict[int, int] = {}
        self.busy_until = 0.0       # address 17 answers its first request then

    def log(self, kind: str, when: float, data: bytes) -> None:
        if self.record:
            self.record.write(f"{when:.6f} {kind} {data.hex(' ')}\n")

    def later(self, delay_s: float, data: bytes) -> None:
        self.seq += 1
        heapq.heappush(self.pending, (time.monotonic() + delay_s, self.seq, data))

    def write_due(self) -> None:
        while self.pending and self.pending[0][0] <= time.monotonic():
            data = heapq.heappop(self.pending)[2]
            self.log("tx", time.monotonic(), data)
            os.write(self.fd, data)

    def handle(self, frame: bytes) -> None:
        address, pdu = frame[0], frame[1:-2]
        self.counts[address] = n = self.counts.get(address, 0) + 1
        reply = adu(address, normal_reply(address, pdu))
        if address == 0 or address == 2:
            return
        if address == 3:
            self.later(self.late_s, reply)
        elif address == 4:
            self.later(0, reply[:-2] + bytes((reply[-2] ^ 0xFF, reply[-1])))
        elif address == 5:
            self.later(0, adu(6, reply[1:-2]))
        elif address == 7:
            function = 0x04 if reply[1] == 0x03 else 0x03
            wrong = bytes((function,)) + reply[2:-2]
            self.later(0, adu(7, wrong))
        elif address == 8:
            self.later(0, adu(9, reply[1:-2]))
            self.later(self.foreign_pause_s, reply)
        elif address == 11:
            self.later(0, adu(11, bytes((pdu[0] | 0x80, 0x02))))
        elif address == 12:
            if n % 2 == 0:
                self.later(0, reply)
        elif address == 13 and not self.garbage_pause_s:
            self.later(0, self.garbage + reply)
        elif address == 13:
            self.later(0, self.garbage)
            self.later(self.garbage_pause_s, reply)
        elif address == 14:
            if n > self.mute_first:
                self.later(0, reply)
        elif address == 18:
            if not self.answer_first < n <= self.answer_first + self.then_mute:
                self.later(self.reply_delay_s, reply)
        elif address == 15:
            self.later(0, self.garbage)
        elif address == 17 and n == 1:
            self.busy_until = time.monotonic() + self.late_s
            self.later(self.late_s, reply)
        elif address == 17:
            busy = self.busy_until - time.monotonic()
            self.later(busy + BUSY_GAP_S if busy > 0 else 0, reply)
        elif address == 16 and pdu[0] in (0x03, 0x04) and reply[2] > 2:
            self.later(0, adu(16, bytes((pdu[0], reply[2] - 2)) + reply[3:-4]))
        else:
            self.later(0, reply)

    def run(self) -> None:
        buf = b""
        first = last = 0.0          # arrival of the frame's first and latest bytes
        while True:
            now = time.monotonic()
            timeouts = [self.pending[0][0] - now] if self.pending else []
            if buf:
                want = request_length(buf)
                timeouts.append(last + (SILENCE_S if want is None else PARTIAL_S) - now)
            timeout = max(0.0, min(timeouts)) if timeouts else None
            readable, _, _ = select.select([self.fd], [], [], timeout)
            now = time.monotonic()
            if readable:
                data = os.read(self.fd, 512)
                if not data:
                    return
                if not buf:
                    first = now
                buf += data
                last = now
            # take every complete frame at the start of buf
            while buf:
                want = request_length(buf)
                if want is None:
                    if now - last < SILENCE_S:
                        break
                    want = len(buf)
                elif want == 0 or len(buf) < want:
                    if now - last >= PARTIAL_S:
                        self.log("rx-bad", first, buf)
                        buf = b""
                    break
                frame, buf = buf[:want], buf[want:]
                if len(frame) < 4 or crc16(frame[:-2]) != frame[-2:]:
                    self.log("rx-bad", first, frame + buf)   # resync: drop what follows too
                    buf = b""
                    break
                self.log("rx", first, frame)
                self.handle(frame)
                first = now
            self.write_due()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("device")
    parser.add_argument("--record", default=None)
    parser.add_argument("--late-ms", type=int, default=800)
    parser.add_argument("--garbage", type=bytes.fromhex, default=bytes.fromhex("55 aa 55"))
    parser.add_argument("--garbage-pause-ms", type=float, default=20)
    parser.add_argument("--foreign-pause-ms", type=float, default=5)
    parser.add_argument("--mute-first", type=int, default=3)
    parser.add_argument("--reply-delay-ms", type=float, default=10)
    parser.add_argument("--answer-first", type=int, default=5)
    parser.add_argument("--then-mute", type=int, default=3)
    args = parser.parse_args()
    fd = open_pty(args.device)
    record = open_record(args.record)
    slave = Slave(fd, record, args.late_ms / 1000, args.garbage, args.garbage_pause_ms / 1000,
                  args.foreign_pause_ms / 1000, args.mute_first, args.reply_delay_ms / 1000,
                  args.answer_first, args.then_mute)
    serve(slave.run, record)


if __name__ == "__main__":
    sys.exit(main())
