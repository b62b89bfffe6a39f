"""What every listener of mbgw shares to stay bounded (Modbus plain and TLS, the table port,
the raw port, the web console, the metrics endpoint, the control socket): an accept() that
fails for want of descriptors or memory rests the listener and is logged once with a count
(it never spins), and a warning about a connection is logged at most once an interval per
address and reason, with how many were left out."""
import errno
import logging
import socket
from collections.abc import Callable

from mbgw.audit import Kind, event
from mbgw.net.ratelimit import RateLimitedLog

# accept() errors that say "not now" (the process or the system is out of something): the
# listener rests, the backlog keeps the newcomers until it tries again
RESOURCE_ERRORS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
REST_FIRST_S = 0.05
REST_MAX_S = 1.0
WARN_INTERVAL_S = 60.0
# a Modbus TCP server's clients (the TCP face's and the table server's)
FIRST_REQUEST_S = 60.0      # a connection that sent no whole request this long is closed
SLOW_REQUEST_S = 0.5        # a request begun this long ago and not whole: a slow client
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

    def accept(self, listener: socket.socket, rest: Callable[[float], None]) -> tuple | None:
        """(socket, address) of a newcomer on listener, or None: none waits, or the process
        is out of descriptors or memory, and then rest(seconds) takes the listener out of its
        loop that long (it would be readable at once again: the loop would spin)."""
        try:
            accepted = listener.accept()
        except (BlockingIOError, InterruptedError, ConnectionAbortedError):
            return None
        except OSError as err:
            if is_resource_error(err):
                rest(self.failed(err))
            else:
                self._log.debug("%s: cannot accept a connection: %s", self._what,
                                err.strerror or err)
            return None
        self.accepted()
        return accepted

    def accepted(self) -> None:
        if self.failures:
            self._log.info("%s: accepting connections again (%d accept() failed meanwhile)",
                           self._what, self.failures)
            self.failures = 0
            self._rest_s = REST_FIRST_S


def is_resource_error(err: OSError) -> bool:
    return err.errno in RESOURCE_ERRORS


class WarnLimit(RateLimitedLog):
    """A warning about one client's connection at most once per interval for each (address,
    reason); the next one says how many were left out meanwhile."""

    def __init__(self, logger: logging.Logger, interval_s: float = WARN_INTERVAL_S,
                 level: int = logging.WARNING) -> None:
        super().__init__(interval_s)
        self._log = logger
        self._level = level

    def warn(self, host: str, why: str, message: str, *args, kind: Kind | None = None,
             **fields) -> bool:
        """Log message % args unless (host, why) was logged within the interval (an audit
        event of kind, with fields, when one is given); True when it was logged."""
        left_out = self.due((host, why))
        if left_out is None:
            return False
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
