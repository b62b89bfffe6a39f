"""Logs kept to one line per interval (a minute, for the refusals of clients and requests):
a client that misbehaves must not be able to fill the log, and the next line says how many
were left out meanwhile."""
import time
from collections.abc import Callable, Hashable

INTERVAL_S = 60.0
MAX_KEYS = 4096         # keys remembered; a flood of new ones forgets the oldest


class RateLimitedLog:
    """Whether a line about key may be logged now: once per interval_s for each key, the
    others counted as left out.  clock: seconds, monotonic (a test's own)."""

    def __init__(self, interval_s: float = INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic,
                 max_keys: int = MAX_KEYS) -> None:
        self._interval_s = interval_s
        self._clock = clock
        self._max_keys = max_keys
        self._last: dict[Hashable, tuple[float, int]] = {}   # -> (when logged, left out)

    def due(self, key: Hashable = None) -> int | None:
        """None when a line about key was logged within the interval (this one is counted as
        left out); else how many were left out since its last line (0: none, or the first),
        and the caller logs now."""
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last[0] < self._interval_s:
            self._last[key] = (last[0], last[1] + 1)
            return None
        if last is None and len(self._last) >= self._max_keys:
            del self._last[next(iter(self._last))]
        self._last.pop(key, None)       # to the end: the oldest logged stay first
        self._last[key] = (now, 0)
        return last[1] if last is not None else 0
