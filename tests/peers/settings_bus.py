"""A serial bus of slaves that each answer only at their own baud rate and format, as real
devices do, on a pty this script makes itself.

usage: settings_bus.py LINK [--unit UNIT,BAUD,FORMAT,DELAY_MS,IDENTITY]... [--record PATH]

LINK becomes a symlink to the pty's device, for the gateway.  Each --unit is a slave: it
answers a request only while the gateway's side of the pty has BAUD and FORMAT, after
DELAY_MS.  IDENTITY: "fc17" answers FC 17 (Report Server ID) itself with SERVER_ID and FC 43
with exception 01; "relay=PATH" hands every request to a real slave on PATH (a socat pty whose
other end a pymodbus_slave.py --identity --silent-unknown serves) and answers with its reply;
"none" answers FC 43 and FC 17 with exception 01.  FC 3 is answered with register i =
1000 + i.  Prints READY, then nothing on stdout.  --record: each request as
"<time.monotonic()> rx <baud> <format> <hex>", flushed at once.

What a pty carries of its settings (Linux 6.x, found with stty -F on both ends of a socat pair
and by reading the termios of the pty's master): the two ends of a socat pair are two ptys
whose settings are independent, so a slave behind socat cannot see the gateway's.  Here the
script holds the pty's master, whose TCGETS2 returns the termios the gateway set on its
side: the baud rate (c_ospeed, set through BOTHER) and the stop bits (CSTOPB) are kept, and
so is PARODD, but the pty driver clears PARENB (and sets CS8) on every change.  So odd
parity shows, while even parity reads as none: a slave at 8n1 also answers at 8e1, and the
tests give formats in which 8n1 comes before 8e1 (or leave 8e1 out).
"""
import argparse
import fcntl
import heapq
import os
import select
import struct
import termios
import time

if __package__:
    from .wire import crc16, open_record, reply_pdu, rtu, serve
else:
    from wire import crc16, open_record, reply_pdu, rtu, serve

TCGETS2 = 0x802C542A                 # asm-generic/ioctls.h: _IOR('T', 0x2A, struct termios2)
TERMIOS2 = struct.Struct("=4I B 19s 2I")  # iflag oflag cflag lflag, line, cc, ispeed, ospeed
SILENCE_S = 0.003                    # the end of a request frame
RELAY_TIMEOUT_S = 1.0
SERVER_ID = b"\x2aSCRIPTED-SLAVE\xff"   # id 0x2A, "SCRIPTED-SLAVE", run indicator ON


class Unit:
    def __init__(self, spec: str) -> None:
        unit, baud, fmt, delay, identity = spec.split(",", 4)
        self.unit, self.baud, self.delay_s = int(unit), int(baud), int(delay) / 1000
        self.odd, self.two_stops = fmt[1] == "o", fmt[2] == "2"
        self.identity = identity
        self.relay = None
        if identity.startswith("relay="):
            self.relay = os.open(identity.removeprefix("relay="), os.O_RDWR | os.O_NOCTTY)
            os.set_blocking(self.relay, False)

    def hears(self, baud: int, odd: bool, two_stops: bool) -> bool:
        return (baud, odd, two_stops) == (self.baud, self.odd, self.two_stops)

    def reply(self, frame: bytes) -> bytes | None:
        if self.relay is not None:
            os.write(self.relay, frame)
            return read_frame(self.relay, time.monotonic() + RELAY_TIMEOUT_S) or None
        pdu = frame[1:-2]
        if pdu[0] == 0x11 and self.identity == "fc17":
            answer = bytes((0x11, len(SERVER_ID))) + SERVER_ID
        else:
            answer = reply_pdu(pdu, 0x03, bytes((0x83, 0x01)))
        return rtu(bytes((self.unit,)) + answer)


def settings(master: int) -> tuple[int, bool, bool]:
    """The gateway's side: (baud rate, odd parity, two stop bits)."""
    raw = fcntl.ioctl(master, TCGETS2, bytes(TERMIOS2.size))
    cflag, ospeed = TERMIOS2.unpack(raw)[2], TERMIOS2.unpack(raw)[-1]
    return ospeed, bool(cflag & termios.PARODD), bool(cflag & termios.CSTOPB)


def read_frame(fd: int, deadline: float) -> bytes:
    """The bytes up to SILENCE_S of silence after the first (b"" when none before deadline)."""
    if not select.select([fd], [], [], max(0.0, deadline - time.monotonic()))[0]:
        return b""
    data = os.read(fd, 512)
    while select.select([fd], [], [], SILENCE_S)[0]:
        data += os.read(fd, 512)
    return data


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("link")
    parser.add_argument("--unit", action="append", default=[])
    parser.add_argument("--record")
    args = parser.parse_args()
    units = {u.unit: u for u in map(Unit, args.unit)}
    record = open_record(args.record)
    master, slave = os.openpty()        # the slave end stays open: no hangup between users
    os.symlink(os.ttyname(slave), args.link)
    pending: list[tuple[float, bytes]] = []

    def run() -> None:
        while True:
            timeout = max(0.0, pending[0][0] - time.monotonic()) if pending else None
            if select.select([master], [], [], timeout)[0]:
                frame = read_frame(master, time.monotonic())
                baud, odd, two = settings(master)
                if record:
                    shape = f"8{'o' if odd else 'n'}{2 if two else 1}"
                    record.write(f"{time.monotonic():.6f} rx {baud} {shape} {frame.hex(' ')}\n")
                unit = units.get(frame[0]) if len(frame) >= 4 else None
                if unit and crc16(frame[:-2]) == frame[-2:] and unit.hears(baud, odd, two):
                    reply = unit.reply(frame)
                    if reply:
                        heapq.heappush(pending, (time.monotonic() + unit.delay_s, reply))
            while pending and pending[0][0] <= time.monotonic():
                os.write(master, heapq.heappop(pending)[1])

    serve(run, record)


if __name__ == "__main__":
    main()
