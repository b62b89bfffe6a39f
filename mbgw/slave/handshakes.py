"""Slave mode's TLS handshakes (Modbus/TCP Security), non-blocking on the asyncio loop: each
accepted TLS connection waits for its first byte (a connection closed or reset before it is a
health check's probe: counted, no handshake refused), then steps through its handshake as its
socket gets ready, at most MAX_HANDSHAKES at once and each within HANDSHAKE_TIMEOUT_S, so a
flood or garbage on the TLS port costs one wake-up a step and never the line thread or a plain
client."""
import asyncio
import socket
import ssl

from mbgw.net.tls import HANDSHAKE_TIMEOUT_S, MAX_HANDSHAKES, ServerHandshake

HANDSHAKES_PER_ADDRESS = MAX_HANDSHAKES // 8    # one address cannot fill the slots


class Handshake:
    """A TLS connection whose handshake is under way, and what the loop waits for."""
    __slots__ = ("shake", "fd", "address", "timer", "waiting_read")

    def __init__(self, sock: socket.socket, address, context: ssl.SSLContext) -> None:
        self.shake = ServerHandshake(sock, address, context)
        self.fd = self.shake.fd
        self.address = address
        self.timer: asyncio.TimerHandle | None = None
        self.waiting_read: bool | None = None    # which readiness it waits for, if any

    @property
    def sock(self) -> socket.socket:
        """The plain socket until the client's first byte, then the SSLSocket."""
        return self.shake.sock


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
        step, why = handshake.shake.step()
        if step in ("read", "write"):
            self._wait_for(handshake, read=step == "read")
        elif step == "probe":
            self._end(handshake)
            handshake.sock.close()
            self._on_probe(handshake.address[0])
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
