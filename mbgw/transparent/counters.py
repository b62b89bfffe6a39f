"""Transparent mode's counters: named integers the line thread writes, a snapshot for the
status, /metrics and the log at stop."""
from dataclasses import dataclass

from mbgw.ops.counters import _Counting


@dataclass(slots=True)
class TransparentCounters(_Counting):
    frames_received: int = 0       # complete frames on the line (crc errors included)
    frames_stored: int = 0         # written at rx-address
    frames_truncated: int = 0      # stored, cut to the area
    frames_incomplete: int = 0     # the line went quiet for eof-timeout before the end
    crc_errors: int = 0            # --crc: dropped
    frames_sent: int = 0           # from the tx area
    sends_refused: int = 0         # the tx area held no whole frame (length, no end character)
    raw_bytes_in: int = 0          # from the raw client to the line
    raw_bytes_out: int = 0         # frames from the line to the raw client
    raw_bytes_dropped: int = 0     # the raw client did not read them
    raw_refused: int = 0           # raw clients refused (one at a time, authip)
    bytes_sent: int = 0
    bytes_received: int = 0
    noise_bytes: int = 0           # (the serial line's interface: never counted here)
    echo_errors: int = 0
