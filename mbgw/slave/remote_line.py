"""A remote line's thread: a line in slave mode like the others (its queue, matching, retries,
demotion, trace, metrics, status), whose transport is a socket to a device across the network
(mbgw.line.remote) instead of a tty.

What differs from a serial line: the line is never "lost" as a tty is, to be found again at
its path; the RemoteLine connects when a request needs it, and an unreachable device (refused,
or the backoff after a failure) costs the request a 0x0A, not the line.  While the backoff
holds, a request is refused when it comes, without waiting its turn.
"""

from typing import cast

from mbgw.config.lines import LineConfig
from mbgw.config.model import SlaveConfig
from mbgw.errors import SerialError, TargetUnreachable
from mbgw.line.remote import RemoteLine
from mbgw.line.serial_line import SerialLine
from mbgw.ops.counters import RemoteCounters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.routing.queue import Inbox, Scheduler
from mbgw.slave.line_thread import SlaveLineThread


def remote_line(line: LineConfig, counters: RemoteCounters) -> RemoteLine:
    """line's socket, not connected yet."""
    remote = line.remote
    assert remote is not None
    return RemoteLine(line.name, line.serial, remote.kind, remote.host, remote.port,
                      line.connect_delay_ms, counters)


class RemoteLineThread(SlaveLineThread):
    def __init__(self, cfg: SlaveConfig, line: LineConfig, scheduler: Scheduler, server,
                 counters: RemoteCounters, devices: DeviceHealth) -> None:
        self.remote_config = line       # what the next connection is made to (set_target)
        self._remote_counters = counters
        self._remote = remote_line(line, counters)
        # the socket stands where a SerialLine would: it has what the thread uses of one
        # (cfg, port, close; the framing comes from mbgw.slave.framing.framing_for)
        super().__init__(cfg, cast(SerialLine, self._remote), scheduler, server, counters,
                         devices)

    def set_target(self, line: LineConfig) -> None:
        """A reload's new [[line]] (before reconfigure(), from another thread): connect-delay
        applies to the next connection, a new connect from the next turn."""
        self.remote_config = line
        self._remote.connect_delay_ms = line.connect_delay_ms

    @property
    def state(self) -> str:
        return "down" if self._remote.lost else "up"

    @property
    def state_since(self) -> float:
        """A remote line's state is its connection's."""
        return self._remote.lost_or_back

    @property
    def turn_limit_s(self) -> float:
        """A serial line's, and a connection (bounded by stout) with its delay."""
        cfg = self.remote_config
        return super().turn_limit_s + (cfg.serial.stout_ms + cfg.connect_delay_ms) / 1000

    def _open_line(self) -> SerialLine:
        self._remote = remote_line(self.remote_config, self._remote_counters)
        return cast(SerialLine, self._remote)

    def _reopens(self, old, new) -> bool:
        return old.device != new.device     # the URL: another device

    def _lost(self, err: SerialError) -> None:
        """An unreachable device is the line's state (RemoteLine.lost, logged there), not a
        lost line: the next request tries again, once the backoff lets it."""
        if not isinstance(err, TargetUnreachable):
            super()._lost(err)

    def _reopen(self) -> None:
        """A new connect: the line is a new socket at once (it connects when a request
        needs it)."""
        self._reopening = None
        self._line = line = self._open_line()
        self._attach(line)

    def use_inbox(self, inbox: Inbox) -> None:
        super().use_inbox(inbox)
        assert self._exchanges is not None
        self._exchanges.holding = self._holding   # a device in backoff: 0x0A at once

    def _holding(self) -> bool:
        return self._remote.holding
