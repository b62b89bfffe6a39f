"""The serial line's current load: its busy time (Counters.line_busy_ns) sampled once a second
over the last minute, as a percentage of the last 10 s and of the last minute.  The average
since the counters were reset says little of now; these say what the line carries now."""
import asyncio
import time
from collections import deque
from collections.abc import Callable

WINDOWS_S = {"10s": 10, "1min": 60}
SAMPLE_S = 1.0


class LineLoad:
    def __init__(self, busy_ns: Callable[[], int], clock=time.monotonic) -> None:
        self._busy_ns = busy_ns
        self._clock = clock
        self._samples: deque[tuple[float, int]] = deque(
            maxlen=int(max(WINDOWS_S.values()) / SAMPLE_S) + 2)

    def sample(self) -> None:
        now, busy = self._clock(), self._busy_ns()
        if self._samples and busy < self._samples[-1][1]:
            self._samples.clear()           # the counters were reset: start again
        self._samples.append((now, busy))

    def percent(self) -> dict[str, float]:
        """{"10s": pct, "1min": pct}, each 0..100: the busy share of that window (of the time
        sampled so far, while the daemon is younger than the window)."""
        self.sample()
        now, busy = self._samples[-1]
        shares = {}
        for name, window in WINDOWS_S.items():
            then, was = next(((t, b) for t, b in self._samples if t >= now - window - 0.5),
                             self._samples[-1])
            span = now - then
            shares[name] = 0.0 if span <= 0 else \
                round(min(100.0, 100 * (busy - was) / 1e9 / span), 2)
        return shares

    async def keep(self) -> None:
        """Sample once a second, until cancelled (the daemon's asyncio loop)."""
        while True:
            self.sample()
            await asyncio.sleep(SAMPLE_S)


def average_percent(busy_ns: int, seconds: float) -> float:
    """The busy share since the counters were reset, 0..100 (a transaction is counted whole
    when it ends, so the share of a short time can overshoot: it is capped)."""
    return round(min(100.0, 100 * busy_ns / 1e9 / max(seconds, 1e-9)), 2)
