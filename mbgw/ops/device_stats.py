"""What each serial device (serial address) has done, and how healthy it looks.

In slave mode a device is a slave on the line; in master mode it is an address mbgw answers
for on the line, whose upstream is the server and unit the slaveid table maps it to.

Written by the line thread only; read (racily, which is fine for figures) by the asyncio
thread for status and metrics.  Health is judged from recent outcomes and logged once per
change, never per failure.

Health also drives the line (demotion, HealthRule): an address is down after `down_after`
transactions in a row without a valid reply and no valid reply for `down_after` x its stout
(a rule without a stout: the count alone); while it is down its requests do not go on the
line (admit() says so, the caller refuses them at once) but for one probe per interval, the
interval doubling while the probes fail; the first answer, an exception reply included, ends
it.  HealthRule.down flags the down addresses for whoever must tell at once: the routing, and
slave mode's C shortcut, which hands their requests back rather than putting them on the line.

The probe (slave mode).  The line thread keeps, per address, a request to probe it with
(probe_adu): the last answered request that writes nothing (pdu.READ_ONLY), or, before any,
the first request that timed out if it writes nothing.  With one kept, the line thread sends
the probes itself (probe_due) and every other request is refused while the address is down;
without, the next request admitted is the probe, as in master mode.  A probe waits for the
device's learnt response time (probe_timeout_ms): 3 x the p99 of its last LEARNT answers, in
[PROBE_TIMEOUT_MIN_MS, stout]; before it has answered, the line's (the last LEARNT answers of
any of its devices, DeviceHealth.line_latencies), and its stout before any answer on the line.
A failure counts as silence only the time its request waited (failed's waited_ms), so a
probe's short wait never brings down-after x stout nearer: it only shortens the probe.
"""
import logging
import math
import time
from array import array

from mbgw.audit import Kind, event
from mbgw.config.model import PROBE_BACKOFF_MAX_MS, Demotion

log = logging.getLogger("mbgw.devices")

COUNTS = ("transactions", "replies", "timeouts", "retries", "crc_errors", "invalid_frames",
          "wrong_unit", "wrong_function", "late_replies", "broadcasts", "demoted_rejects")
# Master mode: an address mbgw answers for on the line, standing for a server's unit.
MASTER_COUNTS = ("transactions", "replies", "timeouts", "unreachable", "wrong_unit",
                 "wrong_function", "invalid_frames", "abandoned", "broadcasts",
                 "demoted_rejects")
ALL_COUNTS = tuple(dict.fromkeys(COUNTS + MASTER_COUNTS))
LATENCY_BUCKETS_MS = (2, 5, 10, 25, 50, 100, 250, 500, 1000, 2500, 5000)
RECENT_WINDOW = 20             # outcomes considered for "degraded"
LEARNT = 100                   # the answers whose latency makes the learnt p99
PROBE_TIMEOUT_FACTOR = 3       # a probe waits this many times the learnt p99 ...
PROBE_TIMEOUT_MIN_MS = 20      # ... at least this, at most the device's stout

UP, DEGRADED, DOWN = "up", "degraded", "down"


class HealthRule:
    """The settings of health that a table's devices share, and which addresses are down."""
    __slots__ = ("down_after", "probe_interval_s", "probe_max_s", "down", "stout_ms")

    def __init__(self, settings: Demotion | None = None, down: bytearray | None = None,
                 stout_ms: int = 0) -> None:
        """down: the flags of the rule of the line's other addresses (a device's own rule,
        [[device]], shares them); stout_ms: the devices' stout (0: none, master mode)."""
        self.down = down if down is not None else bytearray(256)   # 1: down (read by C too)
        self.set(settings or Demotion(), stout_ms)

    def set(self, settings: Demotion, stout_ms: int = 0) -> None:
        self.down_after = settings.down_after   # failures in a row that make it down; 0: never
        self.stout_ms = stout_ms
        self.probe_interval_s = settings.probe_interval_ms / 1000
        self.probe_max_s = max(PROBE_BACKOFF_MAX_MS, settings.probe_interval_ms) / 1000

    def describe(self) -> str:
        """How a down address is probed, for the log."""
        if self.probe_max_s == self.probe_interval_s:
            return f"a probe every {self.probe_interval_s:g} s"
        return (f"a probe every {self.probe_interval_s:g} s, backing off to "
                f"{self.probe_max_s:g} s")


class LatencyRing:
    """The latencies of the last LEARNT answers, in a ring allocated once (answers write it on
    the hot path: a store and small ints, nothing allocated), and their p99 when asked."""
    __slots__ = ("values", "at", "full")

    def __init__(self) -> None:
        self.values = array("d", bytes(8 * LEARNT))    # ms
        self.at = 0                    # where the next one goes
        self.full = False              # LEARNT answers have come: the whole ring counts

    def add(self, latency_ms: float) -> None:
        at = self.at
        self.values[at] = latency_ms
        at += 1
        if at == LEARNT:
            at = 0
            self.full = True
        self.at = at

    def p99(self) -> float | None:
        """None: no answer yet; computed when asked (a probe, status), never per answer."""
        n = LEARNT if self.full else self.at
        if not n:
            return None
        return sorted(self.values[:n])[math.ceil(0.99 * n) - 1]


class DeviceStats:
    # the counts (ALL_COUNTS; a mode keeps those of `counts`)
    transactions: int
    replies: int
    timeouts: int
    retries: int
    crc_errors: int
    invalid_frames: int
    wrong_unit: int
    wrong_function: int
    late_replies: int
    broadcasts: int
    demoted_rejects: int
    unreachable: int
    abandoned: int
    __slots__ = ALL_COUNTS + ("address", "name", "counts", "rule", "upstream", "exceptions",
                              "gateway_exceptions", "latency_buckets", "latency_sum_ms",
                              "last_success", "consecutive_failures", "recent_failures",
                              "health", "health_since", "probe_at", "probe_wait_s",
                              "invalid_bytes", "timing", "silent_since", "latencies",
                              "line_latencies", "probe_adu", "first_timeout_seen")

    def __init__(self, address: int | None, counts: tuple = COUNTS,
                 rule: HealthRule | None = None, name: str | None = None,
                 line_latencies: LatencyRing | None = None) -> None:
        """line_latencies: the answers of every device on its line (its own: none shared)."""
        self.address = address         # None: not a serial address (a TCP scenario's server)
        self.name = name or f"device {address}"     # in the log
        self.counts = counts           # the counters this mode keeps (COUNTS, MASTER_COUNTS)
        self.rule = rule if rule is not None else HealthRule()
        self.upstream: tuple[str, int] | None = None   # master mode: (server IP, unit id)
        self.exceptions: dict[int, int] = {}          # exception replies from the device
        self.gateway_exceptions: dict[int, int] = {}  # exception replies mbgw generated
        self.reset_counts()
        self.last_success: float | None = None
        self.consecutive_failures = 0
        # the bytes received since the last valid reply, in no valid reply (slave mode)
        self.invalid_bytes = 0
        self.recent_failures = 0                      # bit i: the i-th latest outcome failed
        self.health = UP
        self.health_since = time.time()
        self.probe_at = 0.0            # while down: when the next probe may go (monotonic)
        self.probe_wait_s = 0.0        # while down: the interval after a failed probe
        self.timing: dict | None = None    # its own timing ([[device]]), as status shows it
        # since when no valid reply came (monotonic; None: no failure since the last one)
        self.silent_since: float | None = None
        self.latencies = LatencyRing()     # its own last answers'
        self.line_latencies = line_latencies if line_latencies is not None else LatencyRing()
        self.probe_adu: bytes | None = None    # the request its probes repeat (slave mode)
        self.first_timeout_seen = False

    def admit(self, now: float) -> bool:
        """Whether a request for this address goes on the line at `now` (time.monotonic()):
        always unless it is down; while it is down, only the probe, one per interval (the
        next one an interval later whatever becomes of this one).  A request not admitted is
        counted refused (demoted_rejects)."""
        if self.health != DOWN:
            return True
        if now < self.probe_at or self.probe_adu is not None:   # the line thread probes
            self.demoted_rejects += 1
            return False
        self.probe_at = now + self.probe_wait_s
        return True

    def probe_due(self, now: float) -> bytes | None:
        """The probe to send at `now`, when it is down, one is due and a request is kept
        for it; the next one is due an interval later whatever becomes of this one."""
        if self.health != DOWN or self.probe_adu is None or now < self.probe_at:
            return None
        self.probe_at = now + self.probe_wait_s
        return self.probe_adu

    def probe_timeout_ms(self) -> float:
        """How long its probe waits for the reply: see the module's docstring."""
        stout_ms = self.stout_ms
        p99 = self.learnt_p99_ms()
        if p99 is None:
            p99 = self.line_latencies.p99()
        if p99 is None:
            return stout_ms
        return min(max(PROBE_TIMEOUT_FACTOR * p99, PROBE_TIMEOUT_MIN_MS), stout_ms)

    def learnt_p99_ms(self) -> float | None:
        """The p99 of the latencies of its last LEARNT answers (None: none yet)."""
        return self.latencies.p99()

    def answered(self, latency_ms: float, exception_code: int | None) -> None:
        self.replies += 1
        if exception_code is not None:
            self.exceptions[exception_code] = self.exceptions.get(exception_code, 0) + 1
        self.latency_sum_ms += latency_ms
        bucket = 0
        while bucket < len(LATENCY_BUCKETS_MS) and latency_ms > LATENCY_BUCKETS_MS[bucket]:
            bucket += 1
        self.latency_buckets[bucket] += 1
        self.latencies.add(latency_ms)
        self.line_latencies.add(latency_ms)
        self.last_success = time.time()
        self.silent_since = None
        self.consecutive_failures = 0
        self.invalid_bytes = 0
        self._judge(False)

    def failed(self, invalid_bytes: int = 0, waited_ms: float | None = None) -> None:
        """A request without a valid reply; invalid_bytes: what came all the same; waited_ms:
        how long it waited for the reply (None: its stout)."""
        self.consecutive_failures += 1
        self.invalid_bytes += invalid_bytes
        if self.silent_since is None:  # since the failed request went
            waited = self.stout_ms if waited_ms is None else waited_ms
            self.silent_since = time.monotonic() - waited / 1000
        if self.health == DOWN:        # a probe failed: the next waits twice as long
            self.probe_wait_s = min(2 * self.probe_wait_s, self.rule.probe_max_s)
            self.probe_at = time.monotonic() + self.probe_wait_s
        self._judge(True)

    def reset_counts(self) -> None:
        for name in ALL_COUNTS:
            setattr(self, name, 0)
        self.exceptions = {}
        self.gateway_exceptions = {}
        self.latency_buckets = [0] * (len(LATENCY_BUCKETS_MS) + 1)
        self.latency_sum_ms = 0.0

    def gateway_exception(self, code: int) -> None:
        self.gateway_exceptions[code] = self.gateway_exceptions.get(code, 0) + 1

    def _judge(self, failed: bool) -> None:
        self.recent_failures = ((self.recent_failures << 1) | failed) & ((1 << RECENT_WINDOW) - 1)
        self.rejudge()

    def rejudge(self) -> None:
        """Health by the rule, from the outcomes so far (also after the rule changed)."""
        down_after = self.rule.down_after
        if down_after and self.consecutive_failures >= down_after and self._silent_long():
            health = DOWN
        elif self.recent_failures:
            health = DEGRADED
        else:
            health = UP
        if health != self.health:
            self._change(health)

    @property
    def stout_ms(self) -> int:
        """Its rule's stout; none for what is not a serial address (a TCP scenario's server,
        which shares the line's rule but waits tcpto)."""
        return self.rule.stout_ms if self.address is not None else 0

    def _silent_long(self) -> bool:
        """No valid reply for down_after x stout (or already down: it stays so)."""
        if self.health == DOWN:
            return True
        since = self.silent_since
        return since is not None and \
            time.monotonic() - since >= self.rule.down_after * self.stout_ms / 1000

    def reprobe(self, now: float) -> None:
        """The probe interval has changed: while down, the backoff starts again from it, and
        the next probe is due within one interval."""
        if self.health == DOWN:
            self.probe_wait_s = self.rule.probe_interval_s
            self.probe_at = min(self.probe_at, now + self.probe_wait_s)

    def _probe_from(self, now: float) -> None:
        """Down from now on: the first probe an interval later."""
        self.probe_wait_s = self.rule.probe_interval_s
        self.probe_at = now + self.probe_wait_s

    def _change(self, health: str) -> None:
        self.health = health
        self.health_since = time.time()
        if self.address is not None:
            self.rule.down[self.address] = health == DOWN
        via = f" (server {self.upstream[0]} unit {self.upstream[1]})" if self.upstream else ""
        if health == DOWN:
            self._probe_from(time.monotonic())
            event(log, Kind.DEVICE_DOWN, "%s is down: %d requests in a row without a valid "
                  "reply%s%s; its requests are refused, but for %s", self.name,
                  self.consecutive_failures, via,
                  f"; {self.diagnosis}" if self.diagnosis else "", self.rule.describe(),
                  device=self.name, reason=self.diagnosis)
        elif health == DEGRADED and self.last_success is None:
            failures = self.consecutive_failures
            log.warning("%s is degraded: it has not answered yet (%d request%s without a valid "
                        "reply)%s", self.name, failures, "" if failures == 1 else "s", via)
        elif health == DEGRADED:
            log.warning("%s is degraded: %d of its last %d requests failed%s",
                        self.name, bin(self.recent_failures).count("1"), RECENT_WINDOW,
                        via)
        else:
            event(log, Kind.DEVICE_UP, "%s is up: its last %d requests were answered%s",
                  self.name, RECENT_WINDOW, via, device=self.name)

    @property
    def diagnosis(self) -> str | None:
        """Why its requests fail when bytes came that made no valid reply: the line's
        settings rather than a dead device."""
        if not self.consecutive_failures or not self.invalid_bytes:
            return None
        return (f"answers received but not valid ({self.invalid_bytes} bytes): check baud "
                f"rate, parity, address")

    def snapshot(self) -> dict:
        data = {name: getattr(self, name) for name in self.counts}
        if self.upstream is not None:
            data["upstream"] = {"host": self.upstream[0], "unit": self.upstream[1]}
        data.update(
            address=self.address, health=self.health, health_since=self.health_since,
            last_success=self.last_success, consecutive_failures=self.consecutive_failures,
            diagnosis=self.diagnosis,
            exceptions={f"0x{c:02x}": n for c, n in sorted(self.exceptions.items())},
            gateway_exceptions={f"0x{c:02x}": n
                                for c, n in sorted(self.gateway_exceptions.items())},
            latency_buckets_ms=dict(zip([*map(str, LATENCY_BUCKETS_MS), "+Inf"],
                                        self.latency_buckets, strict=True)),
            latency_sum_ms=round(self.latency_sum_ms, 3),
            next_probe_in_s=round(max(0.0, self.probe_at - time.monotonic()), 3)
            if self.health == DOWN else None)
        if self.timing is not None:
            data["timing"] = self.timing
        p99 = self.learnt_p99_ms()
        if self.stout_ms:
            data.update(learnt_p99_ms=None if p99 is None else round(p99, 3),
                        probe_timeout_ms=round(self.probe_timeout_ms(), 3),
                        stout_ms=self.stout_ms)
        return data


class DeviceHealth:
    """DeviceStats by serial address, created on first use, under one HealthRule, but for
    the addresses with a rule of their own ([[device]] down-after, probe-interval)."""

    def __init__(self, counts: tuple = COUNTS, rule: HealthRule | None = None) -> None:
        self.counts = counts
        self.rule = rule if rule is not None else HealthRule()
        self._own: dict[int, HealthRule] = {}
        self._timing: dict[int, dict] = {}
        self._devices: dict[int, DeviceStats] = {}
        # the answers of all its devices: a probe's wait before its device has answered
        self.line_latencies = LatencyRing()

    def find(self, address: int) -> DeviceStats | None:
        """The address's stats if it has any yet (any thread: nothing is created)."""
        return self._devices.get(address)

    def get(self, address: int) -> DeviceStats:
        stats = self._devices.get(address)
        if stats is None:
            stats = self._devices[address] = DeviceStats(
                address, self.counts, self._rule_of(address),
                line_latencies=self.line_latencies)
            stats.timing = self._timing.get(address)
        return stats

    def set_rule(self, settings: Demotion, own: dict[int, tuple[Demotion, dict]] | None = None,
                 stout_ms: int = 0) -> None:
        """New settings (at start, or a reload, on the line thread): every device is judged
        again by them.  own: by address, a device's own demotion and its timing as status
        shows it (its stout_ms); such a device is listed from now on, even before its first
        request.  stout_ms: the others' stout (0: none, master mode)."""
        own = own or {}
        now = time.monotonic()
        before = {a: self._rule_of(a).probe_interval_s for a in self._devices}
        self.rule.set(settings, stout_ms)
        self._own = {a: HealthRule(demotion, self.rule.down, timing.get("stout_ms", stout_ms))
                     for a, (demotion, timing) in own.items()}
        self._timing = {a: timing for a, (_, timing) in own.items()}
        for address in own:
            self.get(address)
        for address, stats in list(self._devices.items()):
            stats.rule = self._rule_of(address)
            stats.timing = self._timing.get(address)
            stats.rejudge()
            interval = before.get(address)
            if interval is not None and interval != stats.rule.probe_interval_s:
                stats.reprobe(now)

    def _rule_of(self, address: int) -> HealthRule:
        return self._own.get(address, self.rule)

    def probing(self) -> list[DeviceStats]:
        """The devices that are down with a request kept to probe them."""
        return [d for d in self._devices.values()
                if d.health == DOWN and d.probe_adu is not None]

    def all(self) -> list[DeviceStats]:
        return [self._devices[a] for a in sorted(self._devices)]

    def reset(self) -> None:
        """Zero every counter; health and last success are kept (they are state, not
        counts).  In place: the line thread may be in a transaction with one of them (a
        replaced object would swallow that transaction's outcome, health included), and it
        may add a device meanwhile (hence the copy of the values)."""
        for stats in list(self._devices.values()):
            stats.reset_counts()
