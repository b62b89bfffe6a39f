"""Line-wide event counters, one class per mode: named integer fields.  The line thread writes
most of them, the asyncio thread the connection counters and reset(); each write is one
attribute store, safe under the GIL."""
import dataclasses
from dataclasses import dataclass


class _Counting:
    """What both modes' counters do: a snapshot in field order, and reset to zero."""
    __slots__ = ()

    def snapshot(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in self.names()}

    def reset(self) -> None:
        for name in self.names():
            setattr(self, name, 0)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]


@dataclass(slots=True)
class Counters(_Counting):
    """Slave mode's."""
    requests: int = 0
    replies: int = 0
    device_exceptions: int = 0
    gateway_exceptions: int = 0
    timeouts: int = 0
    retries: int = 0
    crc_errors: int = 0
    invalid_frames: int = 0
    wrong_unit: int = 0
    wrong_function: int = 0
    late_replies: int = 0
    late_bytes: int = 0
    noise_bytes: int = 0
    unsolicited_frames: int = 0
    unsolicited_bytes: int = 0
    broadcasts: int = 0
    unroutable: int = 0
    line_down_rejects: int = 0
    demoted_rejects: int = 0
    bytes_sent: int = 0
    bytes_received: int = 0
    echo_errors: int = 0
    line_busy_ns: int = 0
    connections_accepted: int = 0
    connections_refused_authip: int = 0
    connections_refused_limit: int = 0
    connections_evicted: int = 0
    connections_bad_header: int = 0
    connections_refused_tls: int = 0
    connections_tls_probes: int = 0
    connections_timed_out: int = 0


# The Modbus TCP face's listeners, as a firewall rule's listener names them
FACE_LISTENERS = ("plain", "tls", "udp", "rtu")


@dataclass(slots=True)
class FaceCounters(_Counting):
    """One listener of the Modbus TCP face: what came in on it."""
    requests: int = 0
    refused: int = 0            # by authip or the firewall: connections and requests
    retransmissions: int = 0    # udp: a request again within stout, answered from memory
    bad_frames: int = 0         # rtu: a bad CRC; udp: a datagram that is no MBAP frame
    dropped: int = 0            # udp: from a source with as many requests in the gateway
    #                             as a TCP client may have (it is not read meanwhile)


def face_counters() -> dict[str, FaceCounters]:
    return {listener: FaceCounters() for listener in FACE_LISTENERS}


@dataclass(slots=True)
class RemoteCounters(Counters):
    """A remote line's (`connect`): slave mode's, and its connection's."""
    reconnects: int = 0        # connections made to the device after the first
    stray_replies: int = 0     # replies dropped: late, duplicate, or answering no request


@dataclass(slots=True)
class MasterCounters(_Counting):
    """Master mode's; the counters line at stop lists these."""
    requests: int = 0
    replies: int = 0
    device_exceptions: int = 0
    gateway_exceptions: int = 0
    timeouts: int = 0
    unreachable: int = 0
    demoted_rejects: int = 0
    broadcasts: int = 0
    crc_errors: int = 0
    invalid_frames: int = 0
    other_addresses: int = 0
    late_replies: int = 0
    wrong_unit: int = 0
    wrong_function: int = 0
    abandoned: int = 0
    connections_opened: int = 0
    connections_evicted: int = 0
    connections_lost: int = 0
    connections_bad_header: int = 0


NAMES = Counters.names()
MASTER_NAMES = MasterCounters.names()


@dataclass(slots=True)
class TableSlaveCounters(_Counting):
    """The serial slave of the exchange table (VPGate 8.5): frames for its address (with a
    valid check), and the errors of frames for it (broadcasts: the table's own counts)."""
    requests: int = 0
    crc_errors: int = 0
    length_errors: int = 0
    send_failures: int = 0
