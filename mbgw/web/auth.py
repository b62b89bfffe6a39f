"""Who may use the console: the two roles' logins, sessions (a cookie naming one, expiring
when idle and at an absolute age), each session's CSRF token, and the login rate limit per
client address."""
import collections
import dataclasses
import logging
import os
import secrets
import time
from collections.abc import Callable

log = logging.getLogger("mbgw.web")

ROLES = ("admin", "user")
COOKIE = "mbgw_session"
CSRF_HEADER = "X-CSRF-Token"
IDLE_S = 30 * 60                  # a session unused this long is over
ABSOLUTE_S = 12 * 3600            # and any session this old
IDLE_ENV = "MBGW_WEB_IDLE_S"      # tests shorten the idle time (not a setting: no key, no option)
FAILURES_PER_WINDOW = 5           # failed logins from one address within LOGIN_WINDOW_S ...
LOGIN_WINDOW_S = 60.0             # ... after which its attempts are refused (429) until it passes
SESSIONS_PER_ROLE = 32            # a role's oldest goes first: logins cannot grow memory for
                                  # ever, nor one role's end another's sessions


@dataclasses.dataclass
class Session:
    role: str
    csrf: str
    created: float
    used: float


class Sessions:
    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._sessions: dict[str, Session] = {}
        self._clock = clock
        self.idle_s = float(os.environ.get(IDLE_ENV) or IDLE_S)
        self.absolute_s = ABSOLUTE_S

    def open(self, role: str) -> tuple[str, Session]:
        """A new session of role (a new token: a login never keeps the one it came with); at
        SESSIONS_PER_ROLE, that role's oldest ends."""
        mine = [token for token, s in self._sessions.items() if s.role == role]
        if len(mine) >= SESSIONS_PER_ROLE:
            del self._sessions[mine[0]]
        now = self._clock()
        token = secrets.token_urlsafe(32)
        session = Session(role, secrets.token_urlsafe(32), now, now)
        self._sessions[token] = session
        return token, session

    def get(self, token: str | None) -> Session | None:
        """The live session of a cookie (its idle time starts again), None when there is
        none or it has expired (then it is forgotten)."""
        session = self._sessions.get(token) if token else None
        if token is None or session is None:
            return None
        now = self._clock()
        if now - session.used > self.idle_s or now - session.created > self.absolute_s:
            del self._sessions[token]
            return None
        session.used = now
        return session

    def close(self, token: str | None) -> None:
        self._sessions.pop(token or "", None)

    def clear(self) -> None:
        self._sessions.clear()


class LoginLimit:
    """At most FAILURES_PER_WINDOW failed logins per address within LOGIN_WINDOW_S.  An attempt
    counts as a failure from the moment it is let in, before its password is checked (which
    takes time, during which others come): so many attempts at once are refused as surely
    as many in a row."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._failures: dict[str, collections.deque] = {}
        self._clock = clock

    def attempt(self, address: str) -> int:
        """Let an attempt from address in, counted as failed until succeeded(): 0; else the
        seconds until address may try again."""
        failures = self._recent(address)
        if len(failures) >= FAILURES_PER_WINDOW:
            return max(1, int(failures[0] + LOGIN_WINDOW_S - self._clock()) + 1)
        failures.append(self._clock())
        self._failures[address] = failures
        return 0

    def succeeded(self, address: str) -> None:
        """The attempt let in last was right: it no longer counts, nor do the earlier ones."""
        self._failures.pop(address, None)

    def _recent(self, address: str) -> collections.deque:
        """The address's failures within the window (addresses with none are forgotten)."""
        failures = self._failures.get(address, collections.deque())
        limit = self._clock() - LOGIN_WINDOW_S
        while failures and failures[0] < limit:
            failures.popleft()
        if not failures:
            self._failures.pop(address, None)
        return failures
