"""Logging set-up: operators read these lines, so one line per event and levels that mean it.

Three forms, one set of fields (`fields`): under systemd (stderr is the journal's stream),
a native journal record per line, sent to journald's socket with MESSAGE, PRIORITY,
SYSLOG_IDENTIFIER, MBGW_LOGGER and, for an audit event (`mbgw/audit.py`), MESSAGE_ID and its
MBGW_* fields; `--log-format json`, the same fields as one JSON object per line on stderr;
else a text line with a timestamp."""
import datetime
import json
import logging
import os
import socket
import struct
import sys

from mbgw import audit
from mbgw.ops.events import EventRing

FORMATS = ("text", "json")
IDENTIFIER = "mbgw"
JOURNAL_SOCKET = "/run/systemd/journal/socket"   # systemd-journald.service(8), native protocol

# systemd's SyslogLevelPrefix= reads "<N>" at the start of each line.
_SYSLOG_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4,
                    logging.ERROR: 3, logging.CRITICAL: 2}
_MESSAGE = logging.Formatter("%(name)s: %(message)s")


def priority(record: logging.LogRecord) -> int:
    return _SYSLOG_PRIORITY.get(record.levelno, 6)


def fields(record: logging.LogRecord) -> dict[str, str]:
    """What the journal's record (and the JSON line) of a log record holds."""
    out = {"MESSAGE": _MESSAGE.format(record), "PRIORITY": str(priority(record)),
           "SYSLOG_IDENTIFIER": IDENTIFIER, "MBGW_LOGGER": record.name}
    event = audit.of(record)
    if event is not None:
        kind, extra = event
        out["MESSAGE_ID"] = kind.message_id
        out["MBGW_EVENT"] = kind.label
        out.update({f"MBGW_{name.upper()}": str(value) for name, value in extra.items()
                    if value is not None})
    return out


def journal_datagram(record_fields: dict[str, str]) -> bytes:
    """The native protocol: KEY=value lines; a value with a newline as KEY, newline, its
    length (64 bits, little endian), the value, newline."""
    out = bytearray()
    for key, value in record_fields.items():
        data = value.encode("utf-8", "replace")
        if b"\n" in data:
            out += key.encode() + b"\n" + struct.pack("<Q", len(data)) + data + b"\n"
        else:
            out += key.encode() + b"=" + data + b"\n"
    return bytes(out)


class JournalHandler(logging.Handler):
    """Each record as a datagram to journald's socket; a record that cannot go there (no
    journald, its queue full, too big for one datagram) goes to `fallback`, when there is
    one, so no line is lost."""

    def __init__(self, path: str = JOURNAL_SOCKET,
                 fallback: logging.Handler | None = None) -> None:
        super().__init__()
        self.path = path
        self.fallback = fallback
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self._sock.setblocking(False)     # never hold up a line thread for the journal

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._sock.sendto(journal_datagram(fields(record)), self.path)
        except OSError:
            if self.fallback is not None:
                self.fallback.handle(record)
        except Exception:
            self.handleError(record)

    def close(self) -> None:
        self._sock.close()
        super().close()


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        stamp = datetime.datetime.fromtimestamp(record.created, datetime.timezone.utc)
        return json.dumps({"TIMESTAMP": stamp.isoformat(timespec="milliseconds"),
                           **fields(record)})


class _JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"<{priority(record)}>{super().format(record)}"


def _stderr_is_the_journal() -> bool:
    """systemd.exec(5): JOURNAL_STREAM is the device and inode ("DEV:INODE") of the stream
    systemd connected stderr to; stderr is still the journal only if it is that same file
    (not redirected, nor a child's that inherited the variable)."""
    try:
        device, inode = map(int, os.environ.get("JOURNAL_STREAM", "").split(":"))
        stat = os.fstat(sys.stderr.fileno())
    except (ValueError, OSError, AttributeError):   # unset, malformed, no real stderr
        return False
    return (stat.st_dev, stat.st_ino) == (device, inode)


def setup(level: str, log_format: str = "text") -> None:
    stream = logging.StreamHandler(sys.stderr)
    handler: logging.Handler = stream
    if log_format == "json":
        stream.setFormatter(JsonFormatter())
    elif _stderr_is_the_journal():
        stream.setFormatter(_JournalFormatter("%(name)s: %(message)s"))
        handler = JournalHandler(JOURNAL_SOCKET, fallback=stream)
    else:
        stream.setFormatter(logging.Formatter(
            "%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger("mbgw")
    # The old handler is not closed: a thread may be in its emit(); its journal socket
    # closes once nothing holds it any more.  The console's events stay.
    root.handlers[:] = [handler, *(h for h in root.handlers if isinstance(h, EventRing))]
    root.setLevel(level.upper())
    root.propagate = False


def journal_event(logger_name: str, kind: audit.Kind, message: str, **event_fields) -> None:
    """For a command that is not the daemon (`mbgw config set`): the event straight to the
    journal, when this machine has one; nothing otherwise (the command says what it did)."""
    record = logging.LogRecord(logger_name, kind.level, "", 0, message, None, None)
    setattr(record, audit.RECORD_ATTRIBUTE, (kind, event_fields))
    handler = JournalHandler(JOURNAL_SOCKET)
    try:
        handler.emit(record)
    finally:
        handler.close()
