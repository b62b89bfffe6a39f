"""A remote line's thread: a line in slave mode like the others (its queue, matching, retries,
demotion, trace, metrics, status), whose transport is a socket to a device across the network
(mbgw.line.remote) instead of a tty.

What differs from a serial line: the line is never "lost" as a tty is, to be found again at
its path; the RemoteLine connects when a request needs it, and an unreachable device (refused,
or the backoff after a failure) costs the request a 0x0A, not the line.  While the backoff
holds, a request is refused when it comes, without waiting its turn.

A Modbus TCP line also takes the Modbus TCP face's clients lent to it (mbgw.slave.loans): a
lent client's request goes to the device and its reply to the client in C on this thread
once the line is idle (_take_lent), then the requests the lent clients sent meanwhile, in
turn; each one's books are kept while the device works on the next, or after LULL_MS of
idleness (_idle), before anything else uses the line.
"""
import errno
from typing import cast

from mbgw.config.lines import LineConfig
from mbgw.config.model import SlaveConfig
from mbgw.errors import SerialError, TargetUnreachable
from mbgw.line.native import BEFORE_UNIT, Forward, Reception
from mbgw.line.remote import RemoteLine
from mbgw.line.serial_line import SerialLine
from mbgw.ops.counters import RemoteCounters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.routing.queue import Exchange, Inbox, Job, Scheduler
from mbgw.slave.connections import Client
from mbgw.slave.line_thread import SlaveLineThread
from mbgw.slave.loans import Loans
from mbgw.slave.remote_framing import MbapFraming
from mbgw.slave.transaction import SerialMaster

# A taken request's books wait this long (ms) for the next lent request, whose device time
# they then use, before the idle line keeps them.
LULL_MS = 1
# The lent clients' requests taken one after the other without a poll() between them, at
# most: then the line thread's loop turns (its heartbeat, new settings).
CHAIN_MAX = 64
FAILED = -2         # _take_one: a request taken and not answered in full


def remote_line(line: LineConfig, counters: RemoteCounters) -> RemoteLine:
    """line's socket, not connected yet."""
    remote = line.remote
    assert remote is not None
    return RemoteLine(line.name, line.serial, remote.kind, remote.host, remote.port,
                      line.connect_delay_ms, counters)


class RemoteLineThread(SlaveLineThread):
    def __init__(self, cfg: SlaveConfig, line: LineConfig, scheduler: Scheduler, server,
                 counters: RemoteCounters, devices: DeviceHealth) -> None:
        self.remote_config = line       # what the next connection is made to (set_target)
        self._remote_counters = counters
        self._remote = remote_line(line, counters)
        # the socket stands where a SerialLine would: it has what the thread uses of one
        # (cfg, port, close; the framing comes from mbgw.slave.framing.framing_for)
        # a taken request's books, not kept yet: the job and what its take received
        self._pending: tuple[Job, Reception] | None = None
        self._taken_got: Reception | None = None     # what the take of self._taken got
        self.loans: Loans | None = None     # the face's clients lent to it (Modbus TCP)
        super().__init__(cfg, cast(SerialLine, self._remote), scheduler, server, counters,
                         devices)
        if line.remote is not None and line.remote.kind == "modbus-tcp":
            self.loans = Loans(self._connections, scheduler.wake, self._take_lent)
            self._connections.on_wake = self.loans.adopt
            self.loans.open = self._takes_loans()
            self._remote.mbap.lend_rules(self.loans.units, self._down)

    def set_target(self, line: LineConfig) -> None:
        """A reload's new [[line]] (before reconfigure(), from another thread): connect-delay
        applies to the next connection, a new connect from the next turn."""
        self.remote_config = line
        self._remote.connect_delay_ms = line.connect_delay_ms

    @property
    def state(self) -> str:
        return "down" if self._remote.lost else "up"

    @property
    def state_since(self) -> float:
        """A remote line's state is its connection's."""
        return self._remote.lost_or_back

    @property
    def turn_limit_s(self) -> float:
        """A serial line's, and a connection (bounded by stout) with its delay."""
        cfg = self.remote_config
        return super().turn_limit_s + (cfg.serial.stout_ms + cfg.connect_delay_ms) / 1000

    def _open_line(self) -> SerialLine:
        self._remote = remote_line(self.remote_config, self._remote_counters)
        return cast(SerialLine, self._remote)

    def _attach(self, line) -> None:
        super()._attach(line)
        if self.loans is not None:      # a new socket: its C exchange's rules
            self._remote.mbap.lend_rules(self.loans.units, self._down)

    def _reopens(self, old, new) -> bool:
        return old.device != new.device     # the URL: another device

    def _lost(self, err: SerialError) -> None:
        """An unreachable device is the line's state (RemoteLine.lost, logged there), not a
        lost line: the next request tries again, once the backoff lets it."""
        if not isinstance(err, TargetUnreachable):
            super()._lost(err)

    def _reopen(self) -> None:
        """A new connect: the line is a new socket at once (it connects when a request
        needs it)."""
        self._book_pending()
        self._reopening = None
        self._line = line = self._open_line()
        self._attach(line)

    def use_inbox(self, inbox: Inbox) -> None:
        super().use_inbox(inbox)
        assert self._exchanges is not None
        self._exchanges.holding = self._holding   # a device in backoff: 0x0A at once
        if self.loans is not None:
            self.loans.inbox = inbox
            inbox.loans = self.loans

    def _holding(self) -> bool:
        return self._remote.holding

    # --- the face's clients lent to this line (mbgw.slave.loans) ---

    def _takes_loans(self) -> bool:
        """No cache to ask first and no pause to keep: a lent request may go at once."""
        cfg = self._cfg
        return cfg.cache is None and cfg.serial.interframe_ms == 0 and \
            self._timing.longest_pause_ms == 0

    def _configure(self, old, reopen: bool) -> None:
        self._book_pending()            # the SerialMaster they belong to may be replaced
        super()._configure(old, reopen)
        if self.loans is not None:
            self.loans.open = self._takes_loans()

    def _finish(self) -> None:
        self._book_pending()
        if self.loans is not None:
            self.loans.open = False
            self.loans.give_all_back()
        super()._finish()

    def _turn(self) -> None:
        if self._pending is not None and (self._scheduler.depth or 1 in self._down):
            self._book_pending()        # before a job or a probe uses the line
        super()._turn()

    def _idle(self) -> None:
        loans = self.loans
        if loans is None:
            super()._idle()
            return
        loans.idling = True
        try:
            pending = self._pending
            if pending is None:
                super()._idle()
                return
            self._connections.wait(LULL_MS)    # a take there keeps the books meanwhile
            if self._pending is pending:
                self._book_pending()
        finally:
            loans.idling = False

    def _serve_taken(self, job: Job) -> None:
        """A taken request whose reply did not all go out (its reception, or none when it
        was not sent): served as any exchange from there."""
        self._book_pending()
        got, self._taken_got = self._taken_got, None
        if got is not None and self._master is not None:
            self._master.book_taken(got)
        self._transact(job)

    def _book_pending(self) -> None:
        """The books of the last request taken and answered (none once the line is gone:
        its reply went out, its books with the line)."""
        pending, self._pending = self._pending, None
        if pending is not None and self._master is not None:
            job, got = pending
            self._master.book_taken(got)
            self._transact(job)

    def _forward(self, job: Job) -> Forward:
        """A lent client's reply goes to it from C while the line holds the client."""
        exchange = job.exchange
        loans = self.loans
        if exchange is not None and exchange.taken and loans is not None:
            client, tid, unit, _ = cast(tuple[Client, int, int, str], exchange.context)
            if loans.holds(client):
                return client.forward_target(tid, unit, not self._scheduler.depth)
        return super()._forward(job)

    def _take_lent(self, client: Client) -> bool:
        """Loans, a lent client readable while the line is idle: C takes its request if it
        is one for this line, sends it and forwards the reply.  Then, while nothing else
        waits for the line, the requests the lent clients sent meanwhile, each client in
        turn, with no Python between a reply and the next request but the reply's
        reception.  False: the client goes back to the face (which then answers what was
        taken, if the reply did not all go out)."""
        master, remote = self._master, self._remote
        if master is None or remote.fd < 0:
            return False                # the face's way connects
        loans = self.loans
        assert loans is not None
        if not loans.idling or self._scheduler.depth or self._taken is not None:
            return True                 # it waits in its socket for the idle line
        taken = self._take_one(client, master, remote)
        if taken <= 0:
            return taken == 0           # nothing came after all: still lent
        for _ in range(CHAIN_MAX):
            if not self._may_chain():
                break
            for other in loans.in_turn_after(client):
                taken = self._take_one(other, master, remote)
                if taken < 0:
                    loans.give_back(other)
                    if taken == FAILED:     # self._taken: _turn serves it first
                        return True
                elif taken:
                    client = other
                    break
            else:
                break                   # none has sent a request meanwhile
        return True

    def _may_chain(self) -> bool:
        assert self._exchanges is not None
        return not self._exchanges.inbox.waiting and self._new_cfg is None and \
            not self._stopping and 1 not in self._down

    def _take_one(self, client: Client, master: SerialMaster, remote: RemoteLine) -> int:
        """One take: 1 taken and answered, 0 nothing came; the client goes back: -1 what came
        is not a request for a take, FAILED taken and not answered in full (self._taken,
        served next)."""
        framing = master.framing
        assert isinstance(framing, MbapFraming)
        mbap = remote.mbap
        line_fd = remote.fd
        tid = framing.next_tid()
        status = mbap.take(client.fd, client.flight, line_fd, tid)
        if status != 1:
            return 0 if status == -errno.EAGAIN else -1
        got = mbap.result
        loan = mbap.loan
        counters = self._remote_counters
        counters.bytes_received += got.stale
        job = self._taken_job(client, loan.tid, loan.unit, mbap.taken_adu(), loan.arrived_ns)
        if loan.send_error:
            remote.not_sent(loan.send_error)
            self._taken = job           # _turn sends it on a new connection
            return FAILED
        counters.bytes_sent += loan.adu_len + BEFORE_UNIT
        self._book_pending()            # the last take's, while the device works on this
        n = mbap.reply_to_loan(line_fd, tid, got.sent_ns + self._timing.stout_ns[loan.adu[0]],
                               Forward(client.fd, loan.tid, loan.unit, False, client.flight))
        counters.bytes_received += got.received
        remote.ended(n)
        reception = framing.reception(n)
        if n > 0 and reception.forwarded == n:
            self._pending = (job, reception)
            return 1
        self._taken, self._taken_got = job, reception   # the face writes the rest, or 0x0B
        return FAILED

    def _taken_job(self, client: Client, tid: int, unit: int, adu: bytes,
                   arrived_ns: int) -> Job:
        """A taken request as an exchange of the face's: its outcome and the face's books
        go there as for any other."""
        loans = self.loans
        assert loans is not None
        exchange = Exchange(client, adu[0], adu[1:], arrived_ns, loans.done_of(client),
                            (client, tid, unit, self.line_name))
        exchange.taken = True
        exchange.loan_to = loans
        self._counters.requests += 1
        return Job(None, 0, 0, adu, arrived_ns, exchange=exchange)
