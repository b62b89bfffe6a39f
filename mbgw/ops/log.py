"""Logging set-up: operators read these lines, so one line per event and levels that mean it."""
import logging
import os
import sys

# systemd's SyslogLevelPrefix= reads "<N>" at the start of each line.
_SYSLOG_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4,
                    logging.ERROR: 3, logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"<{_SYSLOG_PRIORITY.get(record.levelno, 6)}>{super().format(record)}"


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


def setup(level: str) -> None:
    handler = logging.StreamHandler(sys.stderr)
    if _stderr_is_the_journal():
        handler.setFormatter(_JournalFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter(
            "%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger("mbgw")
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    root.propagate = False
