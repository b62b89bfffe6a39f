"""The rule for reopening a lost serial device (issue 11, point 4), on real files: an absent
path or a link to a vanished pty is never opened, a file that cannot be a serial line is
logged once and held back, and a pty that appears at the path is opened at once.

The device is opened by native.Port (libmodbus), as the line threads do; the test only counts
the calls."""
import logging
import os

import pytest

from mbgw.line import native
from mbgw.line.supervisor import Reopening


class Opener:
    """Opens the device as the gateway does, counting the attempts."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.attempts = 0
        self.ports = []

    def __call__(self) -> native.Port:
        self.attempts += 1
        port = native.Port(self.path, 19200, "n", 8, 1)
        self.ports.append(port)
        return port

    def close(self) -> None:
        for port in self.ports:
            port.close()


@pytest.fixture
def opener(tmp_path):
    opener = Opener(str(tmp_path / "ttyUSB0"))
    yield opener
    opener.close()


def warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


@pytest.mark.parametrize("pause", [True, False])
def test_an_absent_path_is_only_looked_at(opener, caplog, pause):
    reopening = Reopening(opener.path, pause)
    for _ in range(3):
        assert reopening.attempt(opener) is None
    assert opener.attempts == 0 and not warnings(caplog)


def test_a_link_to_a_vanished_pty_is_absent(opener, caplog, tmp_path):
    os.symlink(str(tmp_path / "pts-gone"), opener.path)     # as socat's link= to a closed pty
    reopening = Reopening(opener.path, pause=False)
    assert reopening.attempt(opener) is None
    assert opener.attempts == 0 and not warnings(caplog)


@pytest.mark.parametrize("make", [os.mkdir, lambda path: open(path, "w").close()],
                         ids=["directory", "regular file"])
def test_a_path_that_cannot_be_opened_is_logged_once_and_held_back(opener, caplog, make):
    make(opener.path)
    reopening = Reopening(opener.path, pause=False)
    for _ in range(3):
        assert reopening.attempt(opener) is None
    assert opener.attempts == 1              # the later looks fall within the backoff
    logged = warnings(caplog)
    assert len(logged) == 1 and opener.path in logged[0] and "backoff" in logged[0], logged


def test_a_device_appearing_where_a_file_failed_is_opened_at_once(opener, caplog, pty):
    open(opener.path, "w").close()
    reopening = Reopening(opener.path, pause=False)
    assert reopening.attempt(opener) is None and opener.attempts == 1
    os.unlink(opener.path)
    os.symlink(pty, opener.path)             # the adapter is back, within the backoff
    assert reopening.attempt(opener) is not None
    assert opener.attempts == 2


def test_the_device_that_just_failed_gets_a_pause(opener, pty):
    os.symlink(pty, opener.path)
    reopening = Reopening(opener.path, pause=True)
    assert reopening.attempt(opener) is None and opener.attempts == 0
    os.unlink(opener.path)                   # it goes away, and comes back
    assert reopening.attempt(opener) is None
    os.symlink(pty, opener.path)
    assert reopening.attempt(opener) is not None
