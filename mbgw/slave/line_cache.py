"""A line's read cache as its thread uses it: reads that share one transaction
(mbgw.routing.cache), asked at admission, at a read's turn, after each transaction and after a
scenario's run.  Nothing here delivers: each call gives the reply to send (job.outcome set), or
None when the read goes on the line."""
import time

from mbgw.config.cache import CacheRule
from mbgw.config.model import SlaveConfig
from mbgw.line.native import Reception
from mbgw.ops.trace import Outcome
from mbgw.protocol import pdu
from mbgw.routing.cache import ReadCache, is_read
from mbgw.routing.queue import Job


class LineCache:
    def __init__(self, reads: ReadCache, rule: CacheRule | None) -> None:
        self.reads = reads
        self.rule = rule       # the line's own ([serial] or [[line]] cache)
        # some rule has applied on this line, so its writes drop what they overlap
        self.caching = rule is not None

    def configure(self, old: SlaveConfig, new: SlaveConfig, empty: bool) -> None:
        """A reload's settings: what was kept is dropped when a rule changed (empty: one of
        the routes' to this line, as slave.targets tells it)."""
        if empty or new.cache != old.cache or route_caches(new) != route_caches(old):
            self.reads.clear()
        self.rule = new.cache
        self.caching = self.caching or new.cache is not None

    def answer(self, job: Job, rule: CacheRule) -> bytes | None:
        """A read at admission, answered at once if an identical read under way, or fresh
        data, answers it."""
        reads = self.reads
        reply = reads.answer(rule, job.adu, job.received_ns, time.monotonic_ns())
        if reply is not None:
            job.outcome = reads.outcome()
        return reply

    def at_turn(self, job: Job, rule: CacheRule) -> bytes | None:
        """A read whose turn has come, answered if an identical read under way since it
        arrived, or fresh data, answers it; else it goes on the line (a miss)."""
        reads = self.reads
        reply = reads.answer(rule, job.adu, job.received_ns, time.monotonic_ns())
        if reply is None:
            reads.missed(job.adu)
            self.caching = True
            return None
        job.outcome = reads.outcome()
        return reply

    def after(self, job: Job, rule: CacheRule | None, got: Reception | None,
              reply: bytes | None) -> bytes | None:
        """After a transaction, before its reply goes out: a read's answer shared and kept,
        dated by the end of the slave's reply (C may have forwarded it already); stale data
        for a read that timed out; a write's overlap dropped.  The reply to send."""
        reads = self.reads
        adu = job.adu
        if rule is None:
            reads.written(adu)
            return reply
        now_ns = time.monotonic_ns()
        if got is not None:
            reads.answered(adu, reply, got.last_byte_ns or now_ns)
            return reply
        if job.outcome == Outcome.TIMEOUT:
            stale = reads.stale(rule, adu, now_ns)
            if stale is not None:
                reply, job.outcome = stale, reads.outcome()
        reads.failed(adu, reply, now_ns)
        return reply

    def stale_for_down(self, job: Job) -> bytes | None:
        """A read refused as its unit is down: stale data if its rule allows."""
        rule = job.cache
        reply = None if rule is None else self.reads.stale(rule, job.adu, time.monotonic_ns())
        if reply is not None:
            job.outcome = self.reads.outcome()
        return reply

    def scenario_filled(self, adu: bytes, reply: bytes | None) -> None:
        """A scenario's read that was answered fills the cache; its write drops what it
        overlaps."""
        if is_read(adu):
            if reply is not None and not reply[0] & pdu.EXCEPTION_FLAG:
                self.reads.answered(adu, reply, time.monotonic_ns())
        else:
            self.reads.written(adu)


def route_caches(cfg: SlaveConfig) -> list:
    """The routes' cache rules: a reload that changes one empties the cache."""
    return [route.cache for route in cfg.routes]
