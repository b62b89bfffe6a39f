"""A monitor line's tty is opened with DTR and RTS lowered before anything else touches it, and
never raised (issue 29), seen in the system calls (strace) of opening the port as the monitor
line does, on a pty.

What a pty can and cannot show: it has no modem control lines, so the kernel refuses
TIOCMBIC/TIOCMGET there (ENOTTY) and no test can read the lines' level; what it shows is
the order of the calls mbgw makes -- the first open of the device, its flock, then at once
TIOCMBIC with DTR and RTS, before libmodbus's open and any termios call -- and that no
TIOCMBIS (raising a line) is ever made.  On a real UART the kernel raises both lines on the
first open itself; the TIOCMBIC right after it is the earliest they can be lowered."""
import re
import shutil
import subprocess
import sys

import pytest

from tests.harness import PtyPair

pytestmark = pytest.mark.integration

OPEN_AS_THE_MONITOR_LINE = """
import sys
from mbgw.config.lines import LineConfig
from mbgw.config.model import SerialConfig
from mbgw.line.serial_line import SerialLine
from mbgw.monitor.line_thread import listening, transmitter_off

line = LineConfig("tap", SerialConfig(sys.argv[1], dtr="high", rts="high"), mode="monitor")
transmitter_off(SerialLine(listening(line).serial)).close()
"""


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace")
def test_dtr_and_rts_are_lowered_first_and_never_raised(tmp_path):
    pair = PtyPair(tmp_path)
    trace = tmp_path / "strace.txt"
    try:
        done = subprocess.run(["strace", "-f", "-o", str(trace), "-e",
                               "trace=openat,flock,ioctl", sys.executable, "-c",
                               OPEN_AS_THE_MONITOR_LINE, pair.gateway],
                              capture_output=True, text=True, timeout=60)
    finally:
        pair.stop()
    assert done.returncode == 0, done.stderr
    # strace -f prefixes each row with its thread id once the process has more than one
    rows = (re.sub(r"^\d+ +", "", row) for row in trace.read_text().splitlines())
    calls = [row for row in rows if re.match(r"(openat|flock|ioctl)\(", row)]
    opened = [i for i, call in enumerate(calls)
              if call.startswith("openat(") and pair.gateway.split("/")[-1] in call
              and "= -1" not in call]
    assert opened, calls
    first = opened[0]
    fd = calls[first].rsplit("= ", 1)[1].strip()
    assert calls[first + 1].startswith(f"flock({fd}, LOCK_EX|LOCK_NB)"), calls[first:]
    assert calls[first + 2].startswith(f"ioctl({fd}, TIOCMBIC, [TIOCM_DTR|TIOCM_RTS])"), \
        calls[first:]
    assert not any("TCSETS" in call or "TCGETS" in call for call in calls[first:first + 2])
    assert not any("TIOCMBIS" in call or "TIOCMSET" in call for call in calls), calls
