"""A restart asked from the console.  Under systemd: `systemctl restart` of the unit the
daemon runs in (no password as root in the unit; its start follows the unit's rules).
Otherwise, or when systemctl refuses, the daemon stops as for SIGTERM, then executes itself
again: the same process id and command line, the configuration file read afresh."""
import asyncio
import logging
import os
import subprocess
import sys
from pathlib import Path

log = logging.getLogger("mbgw.service")

CGROUP = Path("/proc/self/cgroup")


def own_unit() -> str | None:
    """The systemd service this process runs in (systemd sets INVOCATION_ID), else None."""
    if not os.environ.get("INVOCATION_ID"):
        return None
    try:
        lines = CGROUP.read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        for part in reversed(line.rsplit(":", 1)[-1].split("/")):
            if part.endswith(".service"):
                return part
    return None


class Restart:
    """Made before the daemon runs, told its stop event once it serves (serve_mode), asked
    to re-execute once the daemon has stopped and closed everything."""

    def __init__(self) -> None:
        self.stop: asyncio.Event | None = None
        self.wanted = False

    async def __call__(self, who: str) -> str:
        """Starts the restart; how it is done, in words.  Raises OSError when the daemon
        does not serve yet."""
        unit = own_unit()
        if unit is not None:
            proc = await asyncio.create_subprocess_exec(
                "systemctl", "restart", "--no-block", unit,
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            _, err = await proc.communicate()
            if not proc.returncode:
                log.info("restart of %s asked (%s)", unit, who)
                return f"systemctl restart {unit}"
            # as User=mbgw without a polkit rule: the same pid again suits Type=notify too
            log.warning("systemctl restart %s refused (%s): the daemon restarts itself", unit,
                        err.decode(errors="replace").strip() or proc.returncode)
        if self.stop is None:
            raise OSError("the daemon is not serving yet")
        log.info("restarting: the daemon stops and starts again (%s)", who)
        self.wanted = True
        self.stop.set()
        return "the daemon stops and starts again"

    def reexec_if_wanted(self) -> None:
        """Once the daemon has stopped: the same command again, in this process."""
        if not self.wanted:
            return
        logging.shutdown()
        os.execv(sys.executable, [sys.executable, *sys.orig_argv[1:]])
