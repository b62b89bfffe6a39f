"""Who holds a serial device that mbgw cannot claim: the process with a flock(2) on it (every
mbgw line holds one, csrc/tty.c mbgw_tty_lock), else the processes that have it open, as
fuser(1) finds them."""
import os
from pathlib import Path

PROC = Path("/proc")


def device_holders(device: str) -> list[str]:
    """'pid 1234 (mbgw slave --device /dev/ttyS0)' for each process holding device; [] when
    none can be seen (another user's processes hide their descriptors)."""
    try:
        st = os.stat(device)
    except OSError:
        return []
    pids = _flock_holders(st) or _openers(st)
    return [f"pid {pid} ({_command(pid)})" for pid in sorted(pids)]


def _flock_holders(st: os.stat_result) -> set[int]:
    # /proc/locks: "1: FLOCK  ADVISORY  WRITE 1234 00:1a:5 0 EOF"; the file as
    # major:minor:inode of the filesystem holding it (hex, hex, decimal)
    wanted = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    pids: set[int] = set()
    try:
        rows = (PROC / "locks").read_text().splitlines()
    except OSError:
        return pids
    for row in rows:
        fields = row.split()
        if "->" in fields:           # a waiter, not the holder
            continue
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[5] == wanted:
            pids.add(int(fields[4]))
    return pids


def _openers(st: os.stat_result) -> set[int]:
    pids: set[int] = set()
    for fd_dir in PROC.glob("[0-9]*/fd"):
        try:
            descriptors = list(fd_dir.iterdir())
        except OSError:
            continue
        for fd in descriptors:
            try:
                target = os.stat(fd)
            except OSError:
                continue
            if target.st_ino == st.st_ino and target.st_dev == st.st_dev:
                pids.add(int(fd_dir.parent.name))
                break
    pids.discard(os.getpid())
    return pids


def _command(pid: int) -> str:
    try:
        argv = (PROC / str(pid) / "cmdline").read_bytes().rstrip(b"\0").split(b"\0")
    except OSError:
        return "gone"
    words = [a.decode(errors="replace") for a in argv]
    # python -m mbgw ... reads as mbgw ...
    if len(words) > 2 and words[1:3] == ["-m", "mbgw"]:
        words = ["mbgw", *words[3:]]
    return " ".join(words) or "?"
