"""Reads that share one transaction: a line's read cache, on the line's own thread.

A read (FC 1-4) is known by its ADU as it goes on the line: the serial address after the
route's rewrite, the function, the address and the quantity.  Three ways it may be answered
without going on the line, each under the rule (`CacheRule`) of the route it came by:

- **coalesced**: it arrived while an identical read was waiting or on the line; it gets that
  read's answer, an exception reply (or the gateway's 0x0B) included.  A line thread reads
  its clients and inbox only between transactions, so "arrived while" is told by the time the
  kernel dated the request (`received_ns`) against the end of the answer (`Answer.end_ns`).
- **cached**: it lies wholly within one read whose valid reply ended less than `ttl` ago, of
  the same unit and the same function (FC 3 within an FC 3 read, ...).
- **stale**: its own transaction failed (stout), or its unit is down, and such data is less
  than `serve-stale` old.

A write (FC 5, 15: coils; 6, 16, 22, 23: holding registers) drops the data it overlaps once
it has been on the line, whatever its outcome, before its reply is forwarded; a broadcast's
at every address.  Input registers and discrete inputs only age.

Nothing here is touched by a line without a cache: its thread has no ReadCache.
"""
import bisect
from dataclasses import dataclass

from mbgw.config.cache import CacheRule, RouteCache
from mbgw.ops.trace import Outcome
from mbgw.protocol import pdu

READS = frozenset({0x01, 0x02, 0x03, 0x04})
BIT_READS = frozenset({0x01, 0x02})
# The read function whose data each write changes.
WRITTEN = {0x05: 0x01, 0x0F: 0x01, 0x06: 0x03, 0x10: 0x03, 0x16: 0x03, 0x17: 0x03}
# The served ages' histogram bounds (ms), as mbgw_cache_served_age_seconds shows them.
AGE_BUCKETS_MS = (1, 5, 10, 50, 100, 250, 500, 1000, 2500, 5000, 10000, 60000)
# Entries a line keeps at most; past it, the oldest go first.
MAX_ENTRIES = 4096
FIGURES = ("hits", "coalesced", "misses", "stale_served")
HITS, COALESCED, MISSES, STALE = range(4)
NS_PER_MS = 1_000_000


def resolve(override: RouteCache, line_rule: CacheRule | None
            ) -> CacheRule | None:
    """A route's `cache` (None: not given, False: off) over its line's."""
    if override is None:
        return line_rule
    return override or None


def is_read(adu: bytes) -> bool:
    """A read that may be cached: FC 1-4 of one address, whole (address, FC, start, count)."""
    return len(adu) == 6 and adu[1] in READS and adu[0] != pdu.BROADCAST


class Answer:
    """What the line answered a read: the reply PDU, when it ended, whether it is data to
    keep (a valid reply, not an exception) and the range it covers."""
    __slots__ = ("adu", "reply", "end_ns", "keep", "start", "count")

    def __init__(self, adu: bytes, reply: bytes, end_ns: int, keep: bool) -> None:
        self.adu = adu
        self.reply = reply
        self.end_ns = end_ns
        self.keep = keep
        self.start = int.from_bytes(adu[2:4], "big")
        self.count = int.from_bytes(adu[4:6], "big")

    def covers(self, start: int, count: int) -> bool:
        return self.start <= start and start + count <= self.start + self.count

    def cut(self, function: int, start: int, count: int) -> bytes:
        """The reply to the sub-range (start, count) of this read's."""
        offset = start - self.start
        if function in BIT_READS:
            bits = int.from_bytes(self.reply[2:], "little") >> offset
            size = (count + 7) // 8
            data = (bits & ((1 << count) - 1)).to_bytes(size, "little")
        else:
            data = self.reply[2 + 2 * offset:2 + 2 * (offset + count)]
        return bytes((function, len(data))) + data


@dataclass(slots=True)
class AgeHistogram:
    """The ages of what was served from memory (cached, stale), by AGE_BUCKETS_MS."""
    counts: list[int]
    sum_ms: float = 0.0

    @classmethod
    def empty(cls) -> "AgeHistogram":
        return cls([0] * (len(AGE_BUCKETS_MS) + 1))

    def observe(self, age_ms: float) -> None:
        self.counts[bisect.bisect_left(AGE_BUCKETS_MS, age_ms)] += 1
        self.sum_ms += age_ms


class ReadCache:
    """One line's answers to reads: the last answer of each read (coalescing), the data of
    the valid ones by unit and function (ttl, serve-stale), the figures by unit.  Used by
    the line's thread only; status reads the figures from another thread (whole lists)."""

    def __init__(self) -> None:
        # what the last answer() or stale() that found something served: "coalesced",
        # "cached" or "stale", and the data's age (ms); outcome() is the trace's word for it
        self.served = ""
        self.age_ms = 0.0
        self._last: dict[bytes, Answer] = {}           # by ADU
        self._kept: dict[int, dict[bytes, Answer]] = {}   # by address << 8 | function
        self.figures: dict[int, list[int]] = {}        # by unit: FIGURES
        self.ages = AgeHistogram.empty()

    def answer(self, rule: CacheRule, adu: bytes, received_ns: int, now_ns: int
               ) -> bytes | None:
        """A read's reply without the line: coalesced with the answer that ended after it
        arrived, or cached within ttl (outcome() says which); None: it goes on the line."""
        last = self._last.get(adu)
        if last is not None and received_ns and last.end_ns >= received_ns:
            self._count(adu[0], COALESCED)
            self.served = Outcome.COALESCED
            return last.reply
        if rule.ttl_ms:
            since_ns = now_ns - rule.ttl_ms * NS_PER_MS
            if last is not None and last.keep and last.end_ns >= since_ns:
                # the same read, the common hit: its reply as it is, nothing cut or compared
                self._aged(adu[0], last, now_ns, HITS, "cached")
                return last.reply
            found = self._within(adu, since_ns)
            if found is not None:
                return self._served(adu, found, now_ns, HITS, "cached")
        return None

    def stale(self, rule: CacheRule, adu: bytes, now_ns: int) -> bytes | None:
        """Data for a read whose transaction failed (or whose unit is down), no older than
        serve-stale (outcome() says how old); None: there is none."""
        if not rule.serve_stale_ms:
            return None
        found = self._within(adu, now_ns - rule.serve_stale_ms * NS_PER_MS)
        if found is None:
            return None
        return self._served(adu, found, now_ns, STALE, "stale")

    def outcome(self) -> str:
        """The trace's outcome of what the last answer() or stale() served: "coalesced",
        "cached <age> ms", "stale <age> ms"."""
        if self.served == Outcome.COALESCED:
            return Outcome.COALESCED
        return f"{self.served} {self.age_ms:.0f} ms"

    def missed(self, adu: bytes) -> None:
        """A read with a cache rule goes on the line."""
        self._count(adu[0], MISSES)

    def answered(self, adu: bytes, reply: bytes | None, end_ns: int) -> None:
        """What a read that went on the line got (reply None: nothing, a timeout or the line
        lost, the gateway's own reply given instead): shared with what arrived meanwhile,
        kept as data when it is a valid reply."""
        if reply is None:
            return
        keep = not reply[0] & pdu.EXCEPTION_FLAG
        answer = Answer(adu, reply, end_ns, keep)
        self._last[adu] = answer
        if keep:
            kept = self._kept.setdefault(adu[0] << 8 | adu[1], {})
            kept[adu] = answer
        if len(self._last) > MAX_ENTRIES:
            self._forget_oldest()

    def failed(self, adu: bytes, reply: bytes | None, end_ns: int) -> None:
        """The gateway's answer to a read whose transaction failed: shared with the reads
        that arrived meanwhile, never kept as data."""
        if reply is not None:
            self._last[adu] = Answer(adu, reply, end_ns, False)

    def written(self, adu: bytes) -> None:
        """A write went on the line: the data it overlaps is dropped (every address's for a
        broadcast)."""
        function = WRITTEN.get(adu[1])
        if function is None or len(adu) < 6:
            return
        at = 6 if function == 0x03 and adu[1] == 0x17 else 2   # FC 23: its write range
        start = int.from_bytes(adu[at:at + 2], "big")
        count = 1 if adu[1] in (0x05, 0x06, 0x16) else int.from_bytes(adu[at + 2:at + 4], "big")
        address = adu[0]
        for key, kept in list(self._kept.items()):
            if key & 0xFF != function or (address != pdu.BROADCAST and key >> 8 != address):
                continue
            for read, answer in list(kept.items()):
                if answer.start < start + count and start < answer.start + answer.count:
                    del kept[read]
                    self._last.pop(read, None)

    def clear(self) -> None:
        """A reload changed `cache`: nothing kept is served any more."""
        self._last.clear()
        self._kept.clear()

    def _within(self, adu: bytes, since_ns: int) -> Answer | None:
        kept = self._kept.get(adu[0] << 8 | adu[1])
        if not kept:
            return None
        exact = kept.get(adu)
        if exact is not None and exact.end_ns >= since_ns:
            return exact
        start = int.from_bytes(adu[2:4], "big")
        count = int.from_bytes(adu[4:6], "big")
        best = None
        for answer in kept.values():
            if answer.end_ns >= since_ns and answer.covers(start, count) and \
                    (best is None or answer.end_ns > best.end_ns):
                best = answer
        return best

    def _served(self, adu: bytes, found: Answer, now_ns: int, figure: int, word: str
                ) -> bytes:
        self._aged(adu[0], found, now_ns, figure, word)
        if found.adu is adu or found.adu == adu:
            return found.reply
        return found.cut(adu[1], int.from_bytes(adu[2:4], "big"),
                         int.from_bytes(adu[4:6], "big"))

    def _aged(self, unit: int, found: Answer, now_ns: int, figure: int, word: str) -> None:
        """found is served: counted, its age kept for outcome() and the histogram."""
        self.age_ms = age_ms = (now_ns - found.end_ns) / NS_PER_MS
        self.served = word
        self._count(unit, figure)
        self.ages.observe(age_ms)

    def _count(self, unit: int, figure: int) -> None:
        counts = self.figures.get(unit)
        if counts is None:
            counts = self.figures[unit] = [0, 0, 0, 0]
        counts[figure] += 1

    def _forget_oldest(self) -> None:
        """Past MAX_ENTRIES: the older half goes."""
        last = self._last
        for read in list(last)[:len(last) // 2]:
            answer = last.pop(read)
            kept = self._kept.get(read[0] << 8 | read[1])
            if kept is not None and kept.get(read) is answer:
                del kept[read]

    def status(self) -> dict:
        """The figures by unit and the served ages, as `mbgw status` shows them."""
        units = {str(unit): dict(zip(FIGURES, counts, strict=True))
                 for unit, counts in sorted(list(self.figures.items()))}
        ages = self.ages
        return {"units": units, "ages": {"bounds_ms": list(AGE_BUCKETS_MS),
                                         "counts": list(ages.counts), "sum_ms": ages.sum_ms}}
