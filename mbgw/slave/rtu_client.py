"""The RTU-over-TCP face's connections (rtu-port): Clients of mbgw.slave.connections, read on
the same line thread and poll(), whose streams carry RTU frames instead of MBAP."""
import socket
import time

from mbgw.line.native import NO_FORWARD, Forward, rtu_adu, rtu_request_end
from mbgw.slave.connections import Client


class RtuClient(Client):
    """An RTU-over-TCP connection ("TCP with CRC"): RTU frames in the stream, each ending by
    its length and CRC (line/native.rtu_request_end), never by a pause, so a request may come
    in pieces or with others in one segment.  A request with a bad CRC is dropped and
    counted; the connection stays open.  RTU has no transaction id: one request of it is in
    the gateway at a time, so its replies go back in order.  Never read or written by C,
    whose replies are MBAP."""
    listener = "rtu"
    max_in_flight = 1

    def __init__(self, sock: socket.socket, host: str, peer: str, local: str) -> None:
        super().__init__(sock, host, peer, local)
        self._tid = 0               # the gateway's own, for the trace: RTU has none

    def received(self, data, arrived_ns: int) -> list:
        buf = self._buf
        buf += data
        self.arrived_ns = max(arrived_ns, self.resumed_ns)
        now = time.monotonic()
        self.last_active = now
        frames: list[tuple[int, int, bytes]] = []
        end = rtu_request_end(bytes(buf)) if buf else 0
        while end:
            if end < 0:
                del buf[:-end]
                self.face.bad_frames += 1
            elif self.in_flight + len(frames) >= self.max_in_flight:
                break
            else:
                self._tid = (self._tid + 1) & 0xFFFF
                frames.append((self._tid, buf[0], bytes(buf[1:end - 2])))
                del buf[:end]
            end = rtu_request_end(bytes(buf)) if buf else 0
        self.held = end > 0
        self._framed(buf, frames, now)
        return frames

    def send(self, frame: bytes) -> None:
        """frame: the reply as MBAP (Router's), sent as RTU."""
        super().send(rtu_adu(frame[6], frame[7:]))

    def forward_target(self, tid: int, unit: int, yield_cpu: bool) -> Forward:
        return NO_FORWARD

    @property
    def at_rest(self) -> bool:
        return False                    # never the C shortcut's to read
