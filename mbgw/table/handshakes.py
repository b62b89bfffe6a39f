"""The table server's TLS handshakes (Modbus/TCP Security), each a state of the server's poll
loop: stepped when its socket is ready, never blocking the loop or the plain clients, at most
MAX_HANDSHAKES at once (HANDSHAKES_PER_ADDRESS of one address), each with a deadline."""
import select
import socket
import ssl
import time

from mbgw.net.tls import MAX_HANDSHAKES, ServerHandshake
from mbgw.ops.limits import share

HANDSHAKES_PER_ADDRESS = share(MAX_HANDSHAKES) // 2


class _Handshake(ServerHandshake):
    __slots__ = ("deadline",)

    def __init__(self, sock: socket.socket, address, context: ssl.SSLContext,
                 deadline: float) -> None:
        super().__init__(sock, address, context)
        self.deadline = deadline


class Handshakes:
    """The handshakes under way, by fd (`fd in handshakes`, `len(handshakes)`)."""

    def __init__(self, poll: select.poll, on_done, on_refused, on_probe) -> None:
        """on_done(sock, address): the SSLSocket of a finished handshake; on_refused(address,
        reason) and on_probe(): a handshake refused, or closed before a byte (its socket is
        closed for both)."""
        self._poll = poll
        self._on_done = on_done
        self._on_refused = on_refused
        self._on_probe = on_probe
        self._under_way: dict[int, _Handshake] = {}

    def __contains__(self, fd: int) -> bool:
        return fd in self._under_way

    def __len__(self) -> int:
        return len(self._under_way)

    def start(self, context: ssl.SSLContext | None, sock: socket.socket, address,
              timeout_s: float) -> None:
        """Shake hands with an accepted, non-blocking socket within timeout_s, when TLS is on
        and there is room for it; else it is closed and refused."""
        mine = sum(1 for h in self._under_way.values() if h.address[0] == address[0])
        if context is None or len(self._under_way) >= MAX_HANDSHAKES \
                or mine >= HANDSHAKES_PER_ADDRESS:
            sock.close()
            self._on_refused(address, f"{MAX_HANDSHAKES} TLS handshakes under way already"
                             if mine < HANDSHAKES_PER_ADDRESS else
                             f"{mine} TLS handshakes of this address under way already")
            return
        handshake = _Handshake(sock, address, context, time.monotonic() + timeout_s)
        self._under_way[handshake.fd] = handshake
        self._poll.register(handshake.fd, select.POLLIN)
        self.step(handshake.fd)

    def step(self, fd: int) -> None:
        """One step of a client's handshake; the next when its socket is ready for it."""
        handshake = self._under_way[fd]
        step, why = handshake.step()
        if step == "read":
            self._poll.modify(fd, select.POLLIN)
        elif step == "write":
            self._poll.modify(fd, select.POLLOUT)
        elif step == "probe":
            self._end(handshake)
            handshake.sock.close()
            self._on_probe()
        elif step == "failed":
            self._failed(handshake, why)
        else:
            self._end(handshake)
            self._on_done(handshake.sock, handshake.address)

    def wait_ms(self) -> int | None:
        """Until the first deadline, for poll() (None: no handshake under way)."""
        if not self._under_way:
            return None
        first = min(h.deadline for h in self._under_way.values())
        return max(0, int((first - time.monotonic()) * 1000) + 1)

    def expire(self, timeout_s: float) -> None:
        """Refuse the handshakes past their deadline."""
        now = time.monotonic()
        for handshake in [h for h in self._under_way.values() if h.deadline <= now]:
            self._failed(handshake, f"no TLS handshake within {timeout_s:g} s")

    def close(self, allows=None) -> None:
        """Close them all, or those of the hosts allows(host) no longer allows."""
        for handshake in list(self._under_way.values()):
            if allows is None or not allows(handshake.address[0]):
                self._end(handshake)
                handshake.sock.close()

    def _end(self, handshake: _Handshake) -> None:
        del self._under_way[handshake.fd]
        self._poll.unregister(handshake.fd)

    def _failed(self, handshake: _Handshake, reason: str) -> None:
        self._end(handshake)
        handshake.sock.close()
        self._on_refused(handshake.address, reason)
