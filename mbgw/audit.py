"""Audit events: the log lines a security review looks for (refusals, logins, changes of the
configuration, the operator's actions), each with a fixed MESSAGE_ID (systemd's catalog
form: 128 bits as 32 hex digits, the same in every release) and fields that name the client,
the user, the rule, the reason.  An event is an ordinary log record with the text it always
had; `ops/log` writes its id and fields into the journal's record or the JSON line.

    audit.event(log, Kind.FIREWALL_REFUSED, "firewall: refused client %s", peer,
                client=peer, rule="rule 2")

A field named `client` is MBGW_CLIENT in the journal; a field that is None is left out."""
import enum
import logging

RECORD_ATTRIBUTE = "mbgw_audit"     # the LogRecord attribute that carries (kind, fields)


class Kind(enum.Enum):
    """An event kind: its MESSAGE_ID and its level (the journal's PRIORITY)."""
    CONNECTION_REFUSED = ("fd956cd24cc74171a1b8ee420b50e2a9", logging.WARNING)
    FIREWALL_REFUSED = ("e0c031eca8da40939c33e330e9066e2b", logging.WARNING)
    TLS_REFUSED = ("954715271e394b2591722bab14a046ce", logging.WARNING)
    LOGIN_OK = ("9be3c857f46d4d9088c84b0c6933833a", logging.INFO)
    LOGIN_FAILED = ("a5748e34befa420ba87ad7c13996705c", logging.WARNING)
    CONFIG_CHANGED = ("1ce6a4d2f3db44198e8f659af73c0a8f", logging.INFO)
    CLIENT_CLOSED = ("304a30d815dd42b5b8adf9b5c140d26e", logging.INFO)
    COUNTERS_RESET = ("9c9c8f6adcef4a4fa7d11c98bd3fe3ca", logging.INFO)
    DEVICE_DOWN = ("085abf9b65b541d0bffe3f41c4c462ef", logging.WARNING)
    DEVICE_UP = ("abef1020fad34c77ad036c6430c59b30", logging.INFO)
    SCENARIO_ERROR = ("35b4156e3d3740b888146e2ad5673b10", logging.WARNING)

    def __init__(self, message_id: str, level: int) -> None:
        self.message_id = message_id
        self.level = level

    @property
    def label(self) -> str:
        """MBGW_EVENT: connection-refused, firewall-refused, ..."""
        return self.name.lower().replace("_", "-")


def event(logger: logging.Logger, kind: Kind, message: str, *args, level: int | None = None,
          **fields) -> None:
    """Log message % args on logger at kind's level (or level), with kind's id and these
    fields."""
    level = kind.level if level is None else level
    if logger.isEnabledFor(level):
        logger.log(level, message, *args, stacklevel=2,
                   extra={RECORD_ATTRIBUTE: (kind, fields)})


def operator(uid) -> str | None:
    """MBGW_USER of a control command's "uid": "uid 0" from the control socket, "web
    admin@ADDRESS" from the web console as it is."""
    return f"uid {uid}" if isinstance(uid, int) else uid


def of(record: logging.LogRecord) -> tuple[Kind, dict] | None:
    """The kind and fields of a record that is an audit event, else None."""
    return getattr(record, RECORD_ATTRIBUTE, None)
