"""The console's Events page: the last audit events (mbgw.audit: device up and down, scenario
errors, refusals, logins, configuration changes, ...) kept in memory as they are logged, so
that it shows what the journal got.  A logging handler on the "mbgw" logger: fed where the
log lines are written, by whichever thread writes them."""
import collections
import logging

from mbgw import audit

KEPT = 500                         # events kept; the oldest go first
ROOT = "mbgw"


class EventRing(logging.Handler):
    def __init__(self, kept: int = KEPT) -> None:
        super().__init__(logging.INFO)
        self._events: collections.deque[dict] = collections.deque(maxlen=kept)

    def emit(self, record: logging.LogRecord) -> None:
        found = audit.of(record)
        if found is None:
            return
        kind, fields = found
        self._events.append({
            "time": record.created, "event": kind.label,
            "level": logging.getLevelName(record.levelno).lower(),
            "message": record.getMessage(),
            **{name: str(value) for name, value in fields.items() if value is not None}})

    def newest_first(self) -> list[dict]:
        return list(reversed(self._events))

    def attach(self) -> "EventRing":
        logging.getLogger(ROOT).addHandler(self)
        return self

    def detach(self) -> None:
        logging.getLogger(ROOT).removeHandler(self)
