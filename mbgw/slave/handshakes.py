"""Slave mode's TLS handshakes (Modbus/TCP Security), non-blocking on the asyncio loop: each
accepted TLS connection waits for its first byte (a connection closed or reset before it is a
health check's probe: counted, no handshake refused), then steps through its handshake as its
socket gets ready, at most MAX_HANDSHAKES at once and each within HANDSHAKE_TIMEOUT_S, so a
flood or garbage on the TLS port costs one wake-up a step and never the line thread or a plain
client."""
import asyncio
import socket
import ssl

from mbgw.net.tls import (
    HANDSHAKE_TIMEOUT_S,
    MAX_HANDSHAKES,
    first_byte,
    handshake_step,
    start_handshake,
)

HANDSHAKES_PER_ADDRESS = MAX_HANDSHAKES // 8    # one address cannot fill the slots


class Handshake:
    """A TLS connection whose handshake is under way (sock: still the plain socket until the
    client's first byte)."""
    __slots__ = ("sock", "fd", "address", "timer", "waiting_read", "context")

    def __init__(self, sock: socket.socket, address, context: ssl.SSLContext) -> None:
        self.sock = sock
        self.fd = sock.fileno()
        self.address = address
        self.context = context
        self.timer: asyncio.TimerHandle | None = None
        self.waiting_read: bool | None = None    # which readiness it waits for, if any


class Handshakes:
    def __init__(self, loop: asyncio.AbstractEventLoop, on_done, on_failed, on_probe) -> None:
        """on_done(sock, address): the handshake is over; on_failed(host, reason): refused;
        on_probe(host): closed or reset before a byte (the socket is closed for both)."""
        self._loop = loop
        self._on_done = on_done
        self._on_failed = on_failed
        self._on_probe = on_probe
        self._under_way: dict[int, Handshake] = {}     # by fd
        self.timeout_s = HANDSHAKE_TIMEOUT_S

    @property
    def full(self) -> bool:
        return len(self._under_way) >= MAX_HANDSHAKES

    def from_host(self, host: str) -> int:
        """Handshakes under way with host."""
        return sum(1 for h in self._under_way.values() if h.address[0] == host)

    def start(self, context: ssl.SSLContext, sock: socket.socket, address) -> None:
        """Shake hands with an accepted, non-blocking socket."""
        handshake = Handshake(sock, address, context)
        handshake.timer = self._loop.call_later(
            self.timeout_s, self._failed, handshake,
            f"no handshake within {self.timeout_s:g} s")
        self._under_way[handshake.fd] = handshake
        self._step(handshake)

    def close(self) -> None:
        for handshake in list(self._under_way.values()):
            self._end(handshake)
            handshake.sock.close()

    def _step(self, handshake: Handshake) -> None:
        """One step of a client's handshake; the next when its socket is ready for it."""
        if not isinstance(handshake.sock, ssl.SSLSocket):
            heard = first_byte(handshake.sock)
            if heard is None:
                self._wait_for(handshake, read=True)
                return
            if not heard:
                self._end(handshake)
                handshake.sock.close()
                self._on_probe(handshake.address[0])
                return
            tls = start_handshake(handshake.context, handshake.sock)
            if isinstance(tls, str):
                self._failed(handshake, tls)
                return
            handshake.sock = tls
        step, why = handshake_step(handshake.sock)
        if step in ("read", "write"):
            self._wait_for(handshake, read=step == "read")
        elif step == "failed":
            self._failed(handshake, why)
        else:
            self._end(handshake)
            self._on_done(handshake.sock, handshake.address)

    def _wait_for(self, handshake: Handshake, read: bool) -> None:
        loop = self._loop
        if handshake.waiting_read is not read:
            if handshake.waiting_read is not None:
                (loop.remove_reader if handshake.waiting_read else loop.remove_writer)(
                    handshake.fd)
            (loop.add_reader if read else loop.add_writer)(handshake.fd, self._step,
                                                           handshake)
            handshake.waiting_read = read

    def _end(self, handshake: Handshake) -> None:
        self._under_way.pop(handshake.fd, None)
        if handshake.timer is not None:
            handshake.timer.cancel()
        if handshake.waiting_read is not None:
            (self._loop.remove_reader if handshake.waiting_read else self._loop.remove_writer)(
                handshake.fd)
            handshake.waiting_read = None

    def _failed(self, handshake: Handshake, reason: str) -> None:
        self._end(handshake)
        handshake.sock.close()
        self._on_failed(handshake.address[0], reason)
