"""Line serial's own figures in a slave-mode daemon whose Modbus TCP face reaches other
targets too (lines, remote servers): the daemon's counters, which the face and line serial's
thread both count into, less what the face answered off line serial (Router.off_line).  With
no other target, line serial's figures are the daemon's, as they always were (the table's
and the firewall's answers included)."""
from mbgw.ops.counters import Counters

# The counters the face counts for requests that never reach line serial.
FACE_COUNTED = ("requests", "replies", "gateway_exceptions", "unroutable")


class LineShare:
    """Line serial's counters, read as a Counters is (snapshot) by the status and /metrics."""

    def __init__(self, totals: Counters, off_line: Counters, inboxes: dict) -> None:
        """inboxes: the face's other targets (the daemon's dict, kept up to date by reloads);
        while it is empty line serial's figures are the totals."""
        self._totals = totals
        self._off_line = off_line
        self._inboxes = inboxes

    def reset(self) -> None:
        """With the totals' reset: what the face answered off the line, from zero."""
        self._off_line.reset()

    def snapshot(self) -> dict[str, int]:
        counters = self._totals.snapshot()
        if self._inboxes:
            off_line = self._off_line
            for name in FACE_COUNTED:
                # a reset between the two reads must not show a negative count
                counters[name] = max(0, counters[name] - getattr(off_line, name))
        return counters
