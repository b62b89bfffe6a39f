"""What each serial device (serial address) has done, and how healthy it looks.

In slave mode a device is a slave on the line; in master mode it is an address mbgw answers
for on the line, whose upstream is the server and unit the slaveid table maps it to.

Written by the line thread only; read (racily, which is fine for figures) by the asyncio
thread for status and metrics.  Health is judged from recent outcomes and logged once per
change, never per failure.
"""
import logging
import time

log = logging.getLogger("mbgw.devices")

COUNTS = ("transactions", "replies", "timeouts", "retries", "crc_errors", "invalid_frames",
          "wrong_unit", "wrong_function", "late_replies", "broadcasts")
# Master mode: an address mbgw answers for on the line, standing for a server's unit.
MASTER_COUNTS = ("transactions", "replies", "timeouts", "unreachable", "wrong_unit",
                 "wrong_function", "invalid_frames", "abandoned", "broadcasts")
ALL_COUNTS = tuple(dict.fromkeys(COUNTS + MASTER_COUNTS))
LATENCY_BUCKETS_MS = (2, 5, 10, 25, 50, 100, 250, 500, 1000, 2500, 5000)
DOWN_AFTER_FAILURES = 3        # consecutive transactions without a valid reply
RECENT_WINDOW = 20             # outcomes considered for "degraded"

UP, DEGRADED, DOWN = "up", "degraded", "down"


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
    unreachable: int
    abandoned: int
    __slots__ = ALL_COUNTS + ("address", "counts", "upstream", "exceptions",
                              "gateway_exceptions", "latency_buckets", "latency_sum_ms",
                              "last_success", "consecutive_failures", "recent_failures",
                              "health", "health_since")

    def __init__(self, address: int, counts: tuple = COUNTS) -> None:
        self.address = address
        self.counts = counts           # the counters this mode keeps (COUNTS, MASTER_COUNTS)
        self.upstream: tuple[str, int] | None = None   # master mode: (server IP, unit id)
        self.exceptions: dict[int, int] = {}          # exception replies from the device
        self.gateway_exceptions: dict[int, int] = {}  # exception replies mbgw generated
        self.reset_counts()
        self.last_success: float | None = None
        self.consecutive_failures = 0
        self.recent_failures = 0                      # bit i: the i-th latest outcome failed
        self.health = UP
        self.health_since = time.time()

    def answered(self, latency_ms: float, exception_code: int | None) -> None:
        self.replies += 1
        if exception_code is not None:
            self.exceptions[exception_code] = self.exceptions.get(exception_code, 0) + 1
        self.latency_sum_ms += latency_ms
        bucket = 0
        while bucket < len(LATENCY_BUCKETS_MS) and latency_ms > LATENCY_BUCKETS_MS[bucket]:
            bucket += 1
        self.latency_buckets[bucket] += 1
        self.last_success = time.time()
        self.consecutive_failures = 0
        self._judge(False)

    def failed(self) -> None:
        self.consecutive_failures += 1
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
        if self.consecutive_failures >= DOWN_AFTER_FAILURES:
            health = DOWN
        elif self.recent_failures:
            health = DEGRADED
        else:
            health = UP
        if health != self.health:
            self._change(health)

    def _change(self, health: str) -> None:
        self.health = health
        self.health_since = time.time()
        via = f" (server {self.upstream[0]} unit {self.upstream[1]})" if self.upstream else ""
        if health == DOWN:
            log.warning("device %d is down: %d requests in a row without a valid reply%s",
                        self.address, self.consecutive_failures, via)
        elif health == DEGRADED:
            log.warning("device %d is degraded: %d of its last %d requests failed%s",
                        self.address, bin(self.recent_failures).count("1"), RECENT_WINDOW,
                        via)
        else:
            log.info("device %d is up: its last %d requests were answered%s", self.address,
                     RECENT_WINDOW, via)

    def snapshot(self) -> dict:
        data = {name: getattr(self, name) for name in self.counts}
        if self.upstream is not None:
            data["upstream"] = {"host": self.upstream[0], "unit": self.upstream[1]}
        data.update(
            address=self.address, health=self.health, health_since=self.health_since,
            last_success=self.last_success, consecutive_failures=self.consecutive_failures,
            exceptions={f"0x{c:02x}": n for c, n in sorted(self.exceptions.items())},
            gateway_exceptions={f"0x{c:02x}": n
                                for c, n in sorted(self.gateway_exceptions.items())},
            latency_buckets_ms=dict(zip([*map(str, LATENCY_BUCKETS_MS), "+Inf"],
                                        self.latency_buckets, strict=True)),
            latency_sum_ms=round(self.latency_sum_ms, 3))
        return data


class DeviceTable:
    """DeviceStats by serial address, created on first use."""

    def __init__(self, counts: tuple = COUNTS) -> None:
        self.counts = counts
        self._devices: dict[int, DeviceStats] = {}

    def get(self, address: int) -> DeviceStats:
        stats = self._devices.get(address)
        if stats is None:
            stats = self._devices[address] = DeviceStats(address, self.counts)
        return stats

    def all(self) -> list[DeviceStats]:
        return [self._devices[a] for a in sorted(self._devices)]

    def reset(self) -> None:
        """Zero every counter; health and last success are kept (they are state, not
        counts).  In place: the line thread may be in a transaction with one of them (a
        replaced object would swallow that transaction's outcome, health included), and it
        may add a device meanwhile (hence the copy of the values)."""
        for stats in list(self._devices.values()):
            stats.reset_counts()
