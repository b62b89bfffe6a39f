"""When a lost serial device is opened again: one rule for both modes' line threads.

The line thread looks at the device's path every LOOK_S (a stat, links followed: a link to a
vanished pty is absent).  An absent path is only looked at: no open attempt, no log line.  A
file that appears at the path is opened at once.  The file that has just failed, or that
fails to open, is held back: it is tried again after a pause that doubles from
BACKOFF_FIRST_S to BACKOFF_MAX_S, and its first failed open is logged once.
"""
import errno
import logging
import os
import time

from mbgw.errors import SerialError

log = logging.getLogger("mbgw.line")

LOOK_S = 0.1
BACKOFF_FIRST_S = 0.5
BACKOFF_MAX_S = 5.0


def _file_at(path: str) -> tuple[int, int] | None:
    """The file the path leads to now (links followed), or None."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


class Reopening:
    """One device being reopened, from its loss (or new settings) until it opens."""

    def __init__(self, device: str, pause: bool) -> None:
        """pause: the device has just failed, so the file now at its path waits first."""
        self._device = device
        self._held: tuple[int, int] | None = None     # the file backed off
        self._open_at = 0.0
        self._backoff_s = BACKOFF_FIRST_S
        self._warned = False
        if pause:
            self._hold(_file_at(device))

    def attempt(self, open_device):
        """Call open_device() (it raises SerialError) if the device is there and not held
        back; returns what it returned, or None."""
        found = _file_at(self._device)
        if found is None:
            self._held = None
            return None
        if found == self._held and time.monotonic() < self._open_at:
            return None
        try:
            return open_device()
        except SerialError as err:
            self._failed(found, err)
            return None

    def _failed(self, found: tuple[int, int], err: SerialError) -> None:
        if err.errno == errno.ENOENT:       # gone since the look: absent, nothing to hold
            self._held = None
            return
        self._hold(found)
        if not self._warned:
            self._warned = True
            log.warning("%s; trying again with backoff up to %g s", err.strerror,
                        BACKOFF_MAX_S)

    def _hold(self, found: tuple[int, int] | None) -> None:
        if found != self._held:
            self._held, self._backoff_s, self._warned = found, BACKOFF_FIRST_S, False
        self._open_at = time.monotonic() + self._backoff_s
        self._backoff_s = min(self._backoff_s * 2, BACKOFF_MAX_S)
