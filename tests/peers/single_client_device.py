"""A device across the network that takes one client, for the remote lines' tests (issue 26):
a thread with one listening socket on 127.0.0.1 that keeps at most one connection and resets
every other one that comes meanwhile (SO_LINGER 0), as single-connection inverters do.

It answers FC 3 (holding register n holds 100 + n) and FC 6 (the echo) after a delay drawn
from `delays` by a seeded random, and its faults come from magic registers, libmodbus style:
a read from register LATE_REGISTER is answered `late_s` later, one from TWICE_REGISTER twice.
framing "mbap" speaks Modbus TCP (the reply under the request's transaction id), "rtu" RTU
frames with their CRC (`segments` "bytes": each reply cut into 1-byte writes with random gaps
of up to 2 ms; "join": the reply to a read of LATE_REGISTER held back and sent in one write
with the next reply).  Frames are built here from the spec (tests/modbus.py), never by mbgw's
code."""
import random
import socket
import struct
import threading
import time

from tests.modbus import mbap, rtu_frame

LATE_REGISTER = 900
TWICE_REGISTER = 901


class SingleClientDevice:
    def __init__(self, framing: str = "mbap", delays=(0.005, 0.2), late_s: float = 1.0,
                 segments: str = "", seed: int = 26, port: int = 0) -> None:
        self.framing = framing
        self.delays = delays
        self.late_s = late_s
        self.segments = segments
        self._random = random.Random(seed)
        self.requests: list[tuple[int, bytes]] = []   # (unit, PDU), in order
        self.connections = 0            # accepted, one at a time
        self.resets = 0                 # refused while one was open
        self.seen = threading.Condition()
        self._open: socket.socket | None = None
        self._held = b""                # "join": the reply waiting for the next
        self._listener = socket.create_server(("127.0.0.1", port))
        self.port = self._listener.getsockname()[1]
        self._stopping = False
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    @property
    def open(self) -> socket.socket | None:
        """The connection the device has (None: none)."""
        return self._open

    @property
    def url(self) -> str:
        kind = "modbus-tcp" if self.framing == "mbap" else "rtu-over-tcp"
        return f"{kind}://127.0.0.1:{self.port}"

    def stop(self) -> None:
        self._stopping = True
        self._listener.close()
        self.close_connection()

    def close_connection(self) -> None:
        """The device ends the connection it has (as an idle timeout would)."""
        conn, self._open = self._open, None     # closed: the next client is welcome
        if conn is not None:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def wait_requests(self, n: int, timeout: float = 10.0) -> list[tuple[int, bytes]]:
        with self.seen:
            assert self.seen.wait_for(lambda: len(self.requests) >= n, timeout), self.requests
            return list(self.requests)

    def _accept(self) -> None:
        while not self._stopping:
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return
            if self._open is not None:
                self.resets += 1
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                conn.close()
                continue
            self._open = conn
            self.connections += 1
            threading.Thread(target=self._talk, args=(conn,), daemon=True).start()

    def _talk(self, conn: socket.socket) -> None:
        buf = b""
        try:
            while not self._stopping:
                chunk = conn.recv(4096)
                if not chunk:
                    return
                buf += chunk
                while (request := self._cut(buf)) is not None:
                    taken, tid, unit, pdu = request
                    buf = buf[taken:]
                    self._answer(conn, tid, unit, pdu)
        except OSError:
            return
        finally:
            conn.close()
            if self._open is conn:
                self._open = None

    def _cut(self, buf: bytes):
        """(bytes taken, tid, unit, PDU) of the request at buf's start, or None."""
        if self.framing == "mbap":
            if len(buf) < 7 or len(buf) < 6 + struct.unpack(">H", buf[4:6])[0]:
                return None
            length = struct.unpack(">H", buf[4:6])[0]
            return 6 + length, struct.unpack(">H", buf[:2])[0], buf[6], buf[7:6 + length]
        if len(buf) < 8:
            return None
        assert rtu_frame(buf[:6]) == buf[:8], buf.hex(" ")
        return 8, 0, buf[0], buf[1:6]

    def _answer(self, conn: socket.socket, tid: int, unit: int, pdu: bytes) -> None:
        with self.seen:
            self.requests.append((unit, pdu))
            self.seen.notify_all()
        function, start, count = pdu[0], *struct.unpack(">HH", pdu[1:5])
        if function == 6:
            reply = pdu
        else:
            reply = bytes((3, 2 * count)) + b"".join(
                struct.pack(">H", 100 + start + i) for i in range(count))
        frame = mbap(tid, unit, reply) if self.framing == "mbap" \
            else rtu_frame(bytes((unit,)) + reply)
        if start == LATE_REGISTER and self.segments == "join":
            self._held = frame
            return
        time.sleep(self.late_s if start == LATE_REGISTER else self._random.uniform(*self.delays))
        self._send(conn, frame * 2 if start == TWICE_REGISTER else frame)

    def _send(self, conn: socket.socket, frame: bytes) -> None:
        if self.segments == "bytes":
            for byte in frame:
                conn.sendall(bytes((byte,)))
                time.sleep(self._random.uniform(0, 0.002))
        elif self._held:
            conn.sendall(self._held + frame)
            self._held = b""
        else:
            conn.sendall(frame)
