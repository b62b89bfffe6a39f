"""A restart asked from the console.  The daemon stops as for SIGTERM (the table saved, the
clients closed, STOPPING=1), then:
- as the main process of a systemd service that restarts on EX_RESTART (the package's units:
  RestartForceExitStatus=), it exits with that status and systemd starts the unit again: a new
  process and invocation, the unit's own rules.  No polkit rule or root is needed, where
  `systemctl restart` from User=mbgw is refused;
- otherwise it executes itself again: the same process id and command line, the
  configuration file read afresh."""
import asyncio
import logging
import os
import sys
from pathlib import Path

log = logging.getLogger("mbgw.service")

EX_RESTART = 75      # sysexits.h EX_TEMPFAIL; the units' RestartForceExitStatus= names it
CGROUP = Path("/proc/self/cgroup")
ASK_SYSTEMD_S = 5.0


def own_unit() -> str | None:
    """The systemd service whose main process this is, else None: systemd sets INVOCATION_ID
    in a unit's processes and SYSTEMD_EXEC_PID (248+) to the pid it started, which a child of
    the unit's shell or a re-executed daemon does not change."""
    if not os.environ.get("INVOCATION_ID") or os.environ.get("SYSTEMD_EXEC_PID") != str(
            os.getpid()):
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


async def restarts_on_exit(unit: str) -> bool:
    """The unit restarts when the daemon exits with EX_RESTART (`systemctl show`, read-only:
    no privilege); False when systemd cannot be asked (no D-Bus)."""
    try:
        proc = await asyncio.create_subprocess_exec(
            "systemctl", "show", "--property=RestartForceExitStatus", "--value", unit,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL)
    except OSError:
        return False
    try:
        out, _ = await asyncio.wait_for(proc.communicate(), ASK_SYSTEMD_S)
    except asyncio.TimeoutError:
        proc.kill()
        await proc.wait()
        return False
    return proc.returncode == 0 and str(EX_RESTART) in out.decode(errors="replace").split()


class Restart:
    """Made before the daemon runs, told its stop event once it serves (serve_mode), asked
    to finish the restart once the daemon has stopped and closed everything."""

    def __init__(self) -> None:
        self.stop: asyncio.Event | None = None
        self.by_systemd: bool | None = None      # None: no restart asked

    async def __call__(self, who: str) -> str:
        """Starts the restart; how it is done, in words.  Raises OSError when the daemon
        does not serve yet."""
        if self.stop is None:
            raise OSError("the daemon is not serving yet")
        unit = own_unit()
        self.by_systemd = unit is not None and await restarts_on_exit(unit)
        how = f"systemd restarts {unit}" if self.by_systemd else \
            "the daemon stops and starts again"
        log.info("restart asked (%s): %s", who, how)
        self.stop.set()
        return how

    def finish(self) -> None:
        """Once the daemon has stopped: exits for systemd to start the unit again, or the same
        command again in this process; nothing when no restart was asked."""
        if self.by_systemd is None:
            return
        if self.by_systemd:
            raise SystemExit(EX_RESTART)
        logging.shutdown()
        os.execv(sys.executable, [sys.executable, *sys.orig_argv[1:]])
