"""What every listener of mbgw shares to stay bounded (Modbus plain and TLS, the table port,
the raw port, the web console, the metrics endpoint, the control socket): an accept() that
fails for want of descriptors or memory rests the listener and is logged once with a count
(it never spins), and a warning about a connection is logged at most once an interval per
address and reason, with how many were left out."""
import errno
import logging
import time

from mbgw.audit import Kind, event

# accept() errors that say "not now" (the process or the system is out of something): the
# listener rests, the backlog keeps the newcomers until it tries again
RESOURCE_ERRORS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
REST_FIRST_S = 0.05
REST_MAX_S = 1.0
WARN_INTERVAL_S = 60.0
MAX_WARN_KEYS = 4096            # (address, reason) pairs remembered; a flood forgets the oldest
# What one client address may hold of a listener's connections (its share): the rest stays
# for the others.
SHARE_DIVISOR = 4


class AcceptRest:
    """A listener whose accept() failed for want of resources rests, REST_FIRST_S doubling up
    to REST_MAX_S, and says so once (a warning with the error) until it accepts again (an info
    line with how many failures there were)."""

    def __init__(self, logger: logging.Logger, what: str) -> None:
        self._log = logger
        self._what = what
        self.failures = 0               # in the current run of failures
        self.total = 0
        self._rest_s = REST_FIRST_S

    def failed(self, err: OSError) -> float:
        """Seconds the listener rests before its next accept()."""
        self.total += 1
        if not self.failures:
            self._log.warning("%s: cannot accept connections (%s): resting, retried up to "
                              "every %g s until it accepts again", self._what,
                              err.strerror or err, REST_MAX_S)
        self.failures += 1
        rest, self._rest_s = self._rest_s, min(self._rest_s * 2, REST_MAX_S)
        return rest

    def accepted(self) -> None:
        if self.failures:
            self._log.info("%s: accepting connections again (%d accept() failed meanwhile)",
                           self._what, self.failures)
            self.failures = 0
            self._rest_s = REST_FIRST_S


def is_resource_error(err: OSError) -> bool:
    return err.errno in RESOURCE_ERRORS


class WarnLimit:
    """A warning about one client's connection at most once per interval for each (address,
    reason); the next one says how many were left out meanwhile."""

    def __init__(self, logger: logging.Logger, interval_s: float = WARN_INTERVAL_S,
                 level: int = logging.WARNING) -> None:
        self._log = logger
        self._interval_s = interval_s
        self._level = level
        self._last: dict[tuple[str, str], tuple[float, int]] = {}   # -> (when logged, left out)

    def warn(self, host: str, why: str, message: str, *args, kind: Kind | None = None,
             **fields) -> bool:
        """Log message % args unless (host, why) was logged within the interval (an audit
        event of kind, with fields, when one is given); True when it was logged."""
        now = time.monotonic()
        key = (host, why)
        last = self._last.get(key)
        if last is not None and now - last[0] < self._interval_s:
            self._last[key] = (last[0], last[1] + 1)
            return False
        left_out = last[1] if last is not None else 0
        if len(self._last) >= MAX_WARN_KEYS:
            del self._last[next(iter(self._last))]
        self._last.pop(key, None)
        self._last[key] = (now, 0)
        more = f" ({left_out} more like it left out)" if left_out else \
            " (logged at most once a minute per address and reason)"
        if kind is None:
            self._log.log(self._level, message + more, *args)
        else:
            event(self._log, kind, message + more, *args, **fields)
        return True


def share(cap: int) -> int:
    """How many of a listener's cap connections one client address may hold."""
    return max(1, cap // SHARE_DIVISOR)
