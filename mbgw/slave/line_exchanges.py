"""Requests from other faces (the Modbus TCP face, a serial face) on a line's thread: the
Exchanges its Inbox holds, each admitted by the rules of a client's request (line down 0x0A,
address down 0x0B unless it is the probe, the read cache) and queued as a job in its source's
turn; an operator's survey read (SurveyRead) in its own turn, put on the line as `mbgw scan`
does; each outcome to the face whose exchange it is (Exchange.done, on the line's thread)."""
import logging
import time
from typing import Callable, Hashable

from mbgw.line.serial_line import SerialLine
from mbgw.line.survey import ask_once
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.ops.trace import Outcome
from mbgw.protocol import pdu
from mbgw.routing.cache import is_read, resolve
from mbgw.routing.queue import Exchange, Inbox, Job, Queue, Scheduler, SurveyRead
from mbgw.slave.device_timing import DeviceTiming
from mbgw.slave.line_cache import LineCache
from mbgw.slave.transaction import SerialMaster

log = logging.getLogger("mbgw.line")

# Sources (TCP clients, serial faces) whose queue is kept while idle, before idle ones go.
MAX_SOURCES = 256


class LineExchanges:
    # a remote line's backoff (mbgw.line.remote.RemoteLine.holding): while it holds, each
    # exchange is refused when it comes, before the cache is asked
    holding: Callable[[], bool] | None = None

    def __init__(self, inbox: Inbox, scheduler: Scheduler, counters: Counters,
                 devices: DeviceHealth, cache: LineCache, finished,
                 failure: Callable[[Job, int], bytes | None]) -> None:
        """finished: a client's outcome (Router.finished); failure: the reply to a job the
        line cannot serve (the line's `exception` setting)."""
        self.inbox = inbox
        self._scheduler = scheduler
        self._counters = counters
        self._devices = devices
        self._down = devices.rule.down     # the addresses that are down, by address
        self._cache = cache
        self._finished = finished
        self._failure = failure
        self._queues: dict[Hashable, Queue] = {}   # the exchanges' queues, by source

    def admit_all(self, line_up: bool) -> None:
        """What was submitted, each admitted as a job in its source's queue."""
        for exchange in self.inbox.drain():
            try:
                self.admit(exchange, line_up)
            except Exception:   # a bug must cost one request, never the line
                log.exception("internal error admitting %s", exchange.pdu.hex(" "))

    def admit(self, exchange: Exchange, line_up: bool) -> None:
        """As Router._admit: a line that is down refuses at once (0x0A), an address that is
        down too (0x0B) unless this is its probe; otherwise a job in the source's turn."""
        holding = self.holding
        held = holding is not None and holding()     # refused before anything else
        if type(exchange) is SurveyRead and not held:
            self._admit_survey(exchange, line_up)
            return
        counters = self._counters
        counters.requests += 1
        address = exchange.address
        job = Job(None, 0, 0, bytes((address,)) + exchange.pdu, exchange.received_ns,
                  exchange=exchange)
        cache = self._cache
        rule = None if held else resolve(exchange.cache, cache.rule)
        if rule is not None and is_read(job.adu):
            job.cache = rule
            reply = cache.answer(job, rule)
            if reply is not None:
                self.deliver(job, reply)
                return
        if held or not line_up:
            counters.line_down_rejects += 1
            job.outcome = Outcome.LINE_DOWN
            self.deliver(job, self._failure(job, pdu.GATEWAY_PATH_UNAVAILABLE))
            return
        if self._down[address]:
            if not self._devices.get(address).admit(time.monotonic()):
                stale = cache.stale_for_down(job)
                if stale is not None:
                    self.deliver(job, stale)
                    return
                counters.demoted_rejects += 1
                job.outcome = Outcome.DEVICE_DOWN
                self.deliver(job, self._failure(job, pdu.GATEWAY_TARGET_FAILED))
                return
            job.probe = True
        self._scheduler.submit(self._queue_of(exchange.source), job)

    def _admit_survey(self, survey: SurveyRead, line_up: bool) -> None:
        """An operator's survey read: queued in its own turn whether or not its address is
        down (a probe, never refused as down); the line down tells it at once."""
        job = Job(None, 0, 0, bytes((survey.address,)) + survey.pdu, survey.received_ns,
                  probe=True, exchange=survey)
        if not line_up:
            survey.done(survey, None, Outcome.LINE_DOWN)
            return
        self._scheduler.submit(self._queue_of(survey.source), job)

    def deliver(self, job: Job, reply: bytes | None, forwarded: int = -1) -> None:
        """job's outcome to its client (Router.finished), or to the face whose exchange it
        is (its done, on this thread)."""
        exchange = job.exchange
        if exchange is None:
            self._finished(job, reply, forwarded)
        else:
            if reply is not None:
                self._counters.replies += 1     # as the Router counts what it sends
            exchange.forwarded = forwarded
            exchange.done(exchange, reply, job.outcome)

    @staticmethod
    def withdrawn(job: Job) -> bool:
        """An exchange whose source has closed (a TCP client gone: `closed`, read only) does
        not go on the line, as a closed client's queue is discarded; the face is told."""
        exchange = job.exchange
        if exchange is None or not getattr(exchange.source, "closed", False):
            return False
        exchange.done(exchange, None, Outcome.WITHDRAWN)
        return True

    def survey(self, line: SerialLine, master: SerialMaster, survey: SurveyRead,
               timing: DeviceTiming, away) -> tuple[bytes | None, str]:
        """One survey read on the line (mbgw.line.survey.ask_once, RTU), after the silence
        the line owes, and t3.5 of quiet after it so that the next transaction keeps the
        rule; nothing is booked, retried or demoted.  away: the context the line is used in
        (the gate left to the table reader).  The reply and the outcome; a lost line raises
        SerialError."""
        t35_us = line.cfg.t35_us
        owed_us = (master.quiet_until_ns - time.monotonic_ns()) // 1000
        with away:
            answer = ask_once(line, survey.address, survey.pdu, survey.timeout_ms,
                              max(t35_us, owed_us))
            if answer is None and self._answered_before(survey.address):
                _sit_out_late_reply(line, survey.address, timing.stout_ns[survey.address])
            line.port.wait_quiet(time.monotonic_ns(), t35_us)
        if answer is None:
            return None, Outcome.TIMEOUT
        reply, survey.response_ns = answer
        return reply, Outcome.DEVICE_EXCEPTION if reply[0] & pdu.EXCEPTION_FLAG \
            else Outcome.REPLY

    def _answered_before(self, address: int) -> bool:
        """The line has had a valid answer from address (its devices, looked at without
        adding one)."""
        return any(d.address == address and d.last_success for d in self._devices.all())

    def _queue_of(self, source: Hashable) -> Queue:
        queues = self._queues
        queue = queues.get(source)
        if queue is None:
            if len(queues) >= MAX_SOURCES:     # forget the sources with nothing queued
                for gone in [s for s, q in queues.items() if not q.scheduled]:
                    del queues[gone]
            queue = queues[source] = Queue()
        return queue


def _sit_out_late_reply(line: SerialLine, address: int, stout_ns: int) -> None:
    """A device the clients use missed a survey read's (short) timeout: RTU has no
    transaction id, so its late reply would answer a client's next request to it.  The
    line listens for it, up to the device's stout, before anything else goes out."""
    until = time.monotonic_ns() + stout_ns
    while time.monotonic_ns() < until:
        got = line.port.read_reply(until, line.cfg.end_of_frame_us)
        if got.frame is not None and got.frame[0] == address:
            return
