"""The log's format: "<N>" priorities for the journal only when stderr really is the stream
systemd connected (JOURNAL_STREAM names its device and inode, systemd.exec(5)), timestamps
otherwise.  The logging process is real: python -m mbgw's logging set up in a subprocess
whose stderr is a file, as a redirected service's would be."""
import os
import subprocess
import sys

import pytest

from tests.harness import CHECKOUT

LOG_ONE_LINE = ("import logging; from mbgw.ops import log; log.setup('info'); "
                "logging.getLogger('mbgw').warning('one line')")


def _logged(tmp_path, journal_stream: str | None, name: str = "stderr.txt") -> str:
    """What the logging of a process with this JOURNAL_STREAM writes to its stderr, a file."""
    path = tmp_path / name
    path.touch()
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    if journal_stream is not None:
        env["JOURNAL_STREAM"] = journal_stream.format(**_device_inode(path))
    with open(path, "w") as stderr:
        subprocess.run([sys.executable, "-c", LOG_ONE_LINE], stderr=stderr, env=env,
                       cwd=CHECKOUT, check=True, timeout=30)
    return path.read_text()


def _device_inode(path) -> dict:
    stat = os.stat(path)
    return {"dev": stat.st_dev, "ino": stat.st_ino}


def test_journal_priorities_when_stderr_is_the_journal_stream(tmp_path):
    assert _logged(tmp_path, "{dev}:{ino}") == "<4>mbgw: one line\n"


@pytest.mark.parametrize("journal_stream", [
    None,                          # not started by systemd
    "{dev}:{ino}0",                # systemd's stream, but stderr was redirected since
    "{dev}",                       # malformed
    "journal",
])
def test_timestamps_when_stderr_is_something_else(tmp_path, journal_stream):
    text = _logged(tmp_path, journal_stream)
    assert not text.startswith("<")
    assert text.endswith(" WARNING mbgw: one line\n")
