"""Event counters kept by the daemon.  Plain integers: each is written by one thread."""

NAMES = (
    "requests", "replies", "device_exceptions", "gateway_exceptions", "timeouts", "retries",
    "crc_errors", "invalid_frames", "wrong_unit", "wrong_function", "late_replies",
    "late_bytes",
    "noise_bytes",
    "unsolicited_frames", "unsolicited_bytes", "broadcasts", "unroutable", "line_down_rejects",
    "bytes_sent", "bytes_received", "echo_errors", "line_busy_ns",
    "connections_accepted", "connections_refused_authip", "connections_refused_limit",
    "connections_evicted", "connections_bad_header",
)


class Counters:
    __slots__ = NAMES

    def __init__(self) -> None:
        for name in NAMES:
            setattr(self, name, 0)

    def snapshot(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in NAMES}

    def reset(self) -> None:
        for cls in type(self).__mro__:
            for name in getattr(cls, "__slots__", ()):
                setattr(self, name, 0)

# Master mode's own events; the counters line at stop lists these.
MASTER_NAMES = (
    "requests", "replies", "device_exceptions", "gateway_exceptions", "timeouts",
    "unreachable", "broadcasts", "crc_errors", "invalid_frames", "other_addresses",
    "late_replies", "wrong_unit", "wrong_function", "abandoned", "connections_opened",
    "connections_evicted", "connections_lost", "connections_bad_header",
)


class MasterCounters(Counters):
    __slots__ = tuple(name for name in MASTER_NAMES if name not in NAMES)

    def __init__(self) -> None:
        super().__init__()
        for name in self.__slots__:
            setattr(self, name, 0)

    def snapshot(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in MASTER_NAMES}
