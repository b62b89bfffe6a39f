"""Whether a path can ever be the serial device: checked at start, reload and check-config.

A device that is not there yet is fine: USB adapters appear when plugged in, with their
/dev/serial/by-id links (a link to nothing is a device not there yet), and the gateway waits
for it.  What can never be a serial device is refused: a relative path, a path whose file is
there and is not a character device (a regular file, a directory, a socket, a FIFO, a block
device), and a path under something that is not a directory (nothing can ever appear there).
"""
import os
import stat

KINDS = ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"),
         (stat.S_ISSOCK, "a socket"), (stat.S_ISFIFO, "a FIFO"),
         (stat.S_ISBLK, "a block device"))


def device_problem(path: str) -> str | None:
    """Why path can never be a serial device, or None when it is one or may become one."""
    if not path:
        return "device: empty; expected a path such as /dev/ttyUSB0"
    if not os.path.isabs(path):
        return f"device {path!r}: not an absolute path (e.g. /dev/ttyUSB0)"
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return _parent_problem(path)
    except NotADirectoryError:
        return _parent_problem(path)
    except OSError:
        return None     # there, but not readable to us: opening it will tell
    if stat.S_ISCHR(mode):
        return None
    kind = next((name for test, name in KINDS if test(mode)), "not a character device")
    return f"device {path}: {kind}, not a serial device"


def _parent_problem(path: str) -> str | None:
    """A path that is not there: can a file ever appear at it?"""
    parent = os.path.dirname(os.path.normpath(path))
    while True:
        try:
            mode = os.stat(parent).st_mode
        except FileNotFoundError:
            parent = os.path.dirname(parent)     # a directory that may be made later
            continue
        except NotADirectoryError:
            parent = os.path.dirname(parent)
            continue
        except OSError:
            return None
        if stat.S_ISDIR(mode):
            return None
        return f"device {path}: {parent} is not a directory, so nothing can appear there"
