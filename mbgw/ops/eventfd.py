"""The eventfds the threads wake each other with."""
import os


def drain(fd: int) -> None:
    """Take the signal of an eventfd (non-blocking), if there is one."""
    try:
        os.eventfd_read(fd)
    except BlockingIOError:
        pass
