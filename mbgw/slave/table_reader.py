"""The table reader: while the line thread is inside a serial transaction, a second thread
reads the clients, so that a request for the exchange table never waits for the line.

The line thread holds the gate (a lock) at all times except around its blocking serial calls
(SlaveLineThread._transact).  This thread polls the readable clients and the wake-up eventfd
without the gate, then takes it -- which it gets only while the line thread is on the line --
and serves what is ready with Connections' own code: a table request is answered at once, a
request for the line is kept for the line thread (TcpServer.read_meanwhile), which routes it
as soon as it has the gate back, so admission, demotion and the queue stay the line
thread's.  What it polled may have changed before it has the gate (a client read by the line
thread, closed, its fd reused): only the clients Connections knows then are served, and
EAGAIN is normal.  Runs only while the table is on.
"""
import logging
import os
import select
import threading

from mbgw.line import native
from mbgw.slave.connections import Connections

log = logging.getLogger("mbgw.tcp")

_IN = select.POLLIN
# Its name in ps -L and top -H as in Python's threading (the kernel keeps 15 bytes).
THREAD_NAME = "mbgw-tbl-reader"


class Gate:
    """The lock the line thread and the table reader share.  The line thread has it back as
    soon as the reader lets go, before the reader takes it again (a turnstile): a lock alone
    goes to whichever thread runs first, and a reader kept busy by table requests would keep
    the line waiting."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._turnstile = threading.Lock()
        # `with gate.reader_side:` the reader's turn, behind the line thread if it waits;
        # `with gate.line_away:` the line thread without the gate for a blocking call, and
        # first in line to have it back (made once: nothing is allocated per transaction)
        self.reader_side = _ReaderSide(self._lock, self._turnstile)
        self.line_away = _LineAway(self)

    def take_for_line(self) -> None:
        """The line thread's: first in line."""
        with self._turnstile:
            self._lock.acquire()

    def release(self) -> None:
        self._lock.release()


class _ReaderSide:
    __slots__ = ("_lock", "_turnstile")

    def __init__(self, lock: threading.Lock, turnstile: threading.Lock) -> None:
        self._lock = lock
        self._turnstile = turnstile

    def __enter__(self) -> None:
        with self._turnstile:
            pass
        self._lock.acquire()

    def __exit__(self, *exc) -> None:
        self._lock.release()


class _LineAway:
    __slots__ = ("_gate",)

    def __init__(self, gate: Gate) -> None:
        self._gate = gate

    def __enter__(self) -> None:
        self._gate.release()

    def __exit__(self, *exc) -> None:
        self._gate.take_for_line()


class TableReader(threading.Thread):
    def __init__(self, gate: Gate, connections: Connections, wake_fd: int,
                 on_request, responder) -> None:
        """on_request(client, tid, unit, pdu, responder): TcpServer.read_meanwhile.  Made
        under the gate: connections keeps this thread's poll up to date from then on."""
        super().__init__(name=THREAD_NAME, daemon=True)
        self._gate = gate
        self._connections = connections
        self._wake_fd = wake_fd
        self._responder = responder          # this thread's own reply buffer
        self._on_request = lambda client, tid, unit, pdu: on_request(client, tid, unit, pdu,
                                                                     responder)
        self._stop_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._stopping = False
        self._poll = select.poll()
        self._poll.register(self._stop_fd, _IN)
        self._poll.register(wake_fd, _IN)
        connections.attach(self._poll)

    def stop(self) -> None:
        """Called by the line thread, which must then let go of the gate and join."""
        self._stopping = True
        os.eventfd_write(self._stop_fd, 1)

    def run(self) -> None:
        native.name_thread(self.name)
        ready: list = []
        try:
            while True:
                with self._gate.reader_side:
                    if self._stopping:
                        self._connections.detach()
                        return
                    try:
                        self._connections.serve_ready(ready, self._on_request)
                        self._connections.update()
                    except Exception:   # a bug must cost this wake-up, never the thread
                        log.exception("internal error in the table reader")
                ready = self._poll.poll()
        finally:
            os.close(self._stop_fd)
