"""Event counters kept by the daemon.  Plain integers: each is written by one thread."""

NAMES = (
    "requests", "replies", "device_exceptions", "gateway_exceptions", "timeouts", "retries",
    "crc_errors", "invalid_frames", "wrong_unit", "wrong_function", "late_replies",
    "late_bytes",
    "unsolicited_bytes", "broadcasts", "unroutable", "line_down_rejects",
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
