"""A table client's requests, on the table server's thread (mbgw.table.server).  A read takes
whatever the kernel holds (many pipelined requests at once); each whole MBAP frame is checked
by the client's firewall guard (a refused one gets 0x01 and never reaches the table) and
answered by one C call (Table.responder: the frame in, the reply frame out, under the table's
lock), and the replies of one read leave in one send.  Unit id 0 is a broadcast (IDEC): its
writes are done, nothing is sent back.  A protocol id other than 0 or a length outside 2..254
closes that connection only (counted).  A client that does not read its replies is not read
either until the socket has taken them (TCP back-pressure).  Nothing is logged per request.
"""
import errno
import logging
import select
import ssl
import time
from collections.abc import Callable
from typing import cast

from mbgw.errors import BadHeader
from mbgw.firewall.guard import Firewall, Guard
from mbgw.line import native
from mbgw.ops.limits import WarnLimit
from mbgw.table.connection import Connection

log = logging.getLogger("mbgw.table")

RECEIVE_SIZE = 4096           # one read: 15 requests of 260 bytes, 341 reads of 12
BROADCAST_UNIT = 0

_IN = select.POLLIN
_OUT = select.POLLOUT
_HEADER = native.HEADER
_HEADER_LEN = native.HEADER_LEN
_frame_length = native.frame_length


class ClientRequests:
    """The requests of the table server's clients, read, answered and replied to; one
    instance a server, its buffers shared by every client (one thread)."""

    def __init__(self, poll: select.poll, clients: dict[int, Connection],
                 close: Callable[[Connection], None], firewall: Firewall,
                 warn: WarnLimit) -> None:
        """poll: the server's (a client waiting to send is polled for POLLOUT); clients: the
        server's by fd, which a client closed has left; close(client): the server forgets
        and closes it."""
        self._poll = poll
        self._clients = clients
        self._close = close
        self.firewall = firewall           # the server's thread sets new rules (a reload)
        self._warn = warn
        self._input = bytearray(RECEIVE_SIZE)
        self._input_view = memoryview(self._input)
        self._replies = bytearray()        # the replies of one read, sent together
        self.bad_header = 0

    def serve(self, client: Connection, events: int, answer) -> None:
        """What poll() found on the client: held replies sent, requests read and answered."""
        if events & _OUT:
            if not self._flush(client):
                return
        if events & (_IN | select.POLLHUP | select.POLLERR) or client.tls:
            self.receive(client, answer)
        # what SSL has decrypted already, poll() does not see: read before waiting again
        while client.tls and not client.held and client.fd in self._clients \
                and cast(ssl.SSLSocket, client.sock).pending():
            self.receive(client, answer)

    def receive(self, client: Connection, answer) -> None:
        """One read of the client's requests, answered."""
        try:
            n = client.sock.recv_into(self._input)
        except (BlockingIOError, InterruptedError, ssl.SSLWantReadError,
                ssl.SSLWantWriteError):
            return
        except OSError:
            self._close(client)
            return
        if n == 0:
            self._close(client)
            return
        client.last_active = time.monotonic()
        if client.partial:
            client.partial += self._input_view[:n]
            data = bytes(client.partial)
            client.partial.clear()
            view = memoryview(data)
        else:
            view = self._input_view[:n]
        try:
            self._answer_all(client, view, len(view), answer)
        except BadHeader as err:
            self.bad_header += 1
            self._warn.warn(client.host, "bad header", "table client %s: bad MBAP header (%s); "
                            "closing the connection", client.peer, err)
            self._close(client)

    def _answer_all(self, client: Connection, view: memoryview, n: int, answer) -> None:
        """Answer every whole frame in view (n bytes); keep the start of an incomplete one.
        Raises BadHeader once the replies before the bad header are sent."""
        at = 0
        replies = self._replies
        try:
            while n - at >= _HEADER_LEN:
                _, protocol, length, unit = _HEADER.unpack_from(view, at)
                end = _frame_length(protocol, length)
                if end < 0:
                    raise native.bad_header(end, protocol, length)
                end += at
                if end > n:
                    break
                client.requests += 1
                guard = client.guard
                if guard is not None and not guard.allows(unit, view[at + _HEADER_LEN:end]):
                    reply = self._refused(client, guard, view[at:end], unit)
                else:
                    reply = answer(view[at:end], unit == BROADCAST_UNIT)
                at = end
                if not reply:
                    continue
                if not replies and n - at < _HEADER_LEN:
                    self._send(client, reply)    # alone (the common case): sent as it is
                else:
                    replies += reply             # the buffer is the responder's: copied
        finally:
            if replies:
                self._send(client, replies)
                replies.clear()
        if at < n:
            if not client.partial_since or at:
                client.partial_since = time.monotonic()
            client.partial += view[at:n]
        else:
            client.partial_since = 0.0

    def _refused(self, client: Connection, guard: Guard, frame, unit: int) -> bytes:
        """The reply to a request the firewall refused: 0x01, a broadcast's too (it was not
        done)."""
        client.firewall_refused += 1
        refusal = self.firewall.refused(guard, client.peer, client.role, unit,
                                        frame[_HEADER_LEN:])
        return native.frame(_HEADER.unpack_from(frame)[0], unit, refusal)

    def _send(self, client: Connection, data) -> None:
        """Onto the socket now, or held (and the client no longer read) until it takes it."""
        if client.held:
            client.held += data
            return
        try:
            sent = client.sock.send(data)
        except (BlockingIOError, InterruptedError, ssl.SSLWantWriteError,
                ssl.SSLWantReadError):
            sent = 0
        except OSError as err:
            if err.errno not in (errno.EPIPE, errno.ECONNRESET):
                log.debug("table client %s: send: %s", client.peer, err.strerror)
            return                          # the next poll finds the connection broken
        if sent < len(data):
            client.held += memoryview(data)[sent:]
            self._poll.modify(client.fd, _OUT)

    def _flush(self, client: Connection) -> bool:
        """Send held replies; True once none are left (the client is read again)."""
        try:
            sent = client.sock.send(client.held)
        except (BlockingIOError, InterruptedError, ssl.SSLWantWriteError,
                ssl.SSLWantReadError):
            return False
        except OSError:
            self._close(client)
            return False
        del client.held[:sent]
        if client.held:
            return False
        self._poll.modify(client.fd, _IN)
        return True
