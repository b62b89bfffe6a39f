"""systemd's notify protocol (sd_notify(3)): the daemon's state sent to NOTIFY_SOCKET."""
import logging
import os
import socket
import struct

log = logging.getLogger("mbgw")

NOTIFY_WAIT_S = 2        # the longest a change of state waits for room on the notify socket
NOTIFY_WAIT = struct.pack("ll", NOTIFY_WAIT_S, 0)     # struct timeval, for SO_SNDTIMEO


def sd_notify(state: str, wait: bool = True) -> bool:
    """Tell systemd (or a test) about our state, when NOTIFY_SOCKET asks for it; True when
    sent.  A change of state waits while the socket's queue is full, as libsystemd's
    sd_notify does, but NOTIFY_WAIT_S at most; wait=False drops a periodic message instead:
    the event loop must not wait for it."""
    path = os.environ.get("NOTIFY_SOCKET")
    if not path:
        return False
    if path.startswith("@"):
        path = "\0" + path[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
            if wait:        # bounded: a reader that never reads must not keep us from stopping
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, NOTIFY_WAIT)
            sock.sendto(state.encode(), 0 if wait else socket.MSG_DONTWAIT, path)
    except OSError as err:    # nobody listening any more: not our problem to die of
        log.debug("sd_notify %s: %s", state, err)
        return False
    return True
