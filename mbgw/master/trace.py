"""Master mode's events for `mbgw trace` (see mbgw.ops.trace for the fields), built on the line
thread only while someone traces.  Each request of the master that goes upstream is one
"request" event (the Modbus/TCP frame sent, with the serial address), then one "reply" (the
server's frame) or "no reply" event with the outcome and what went back on the line; a frame
for an address outside the slaveid table is one "ignored" event.  A request for the table
address is a "request" event and a "reply" (or, for a broadcast, "no reply") event of server
"table", outcome "table".  A server's reply to an earlier request (late, after tcpto) is a
"late" event, dropped: its serial address is the one its request had, when still known."""
import time

from mbgw.ops.trace import Outcome, TraceEvent

ADDRESSES_KEPT = 256                       # requests whose serial address a late reply finds
TABLE_SERVER = "table"


class MasterTracer:
    def __init__(self, hub) -> None:
        self.hub = hub            # a TraceHub; .active tells whether anyone traces
        self._addresses: dict[tuple[str, int | None], int] = {}    # (server, tid): serial address

    def request(self, adu: bytes, server: str, conn, tid: int | None, unit: int) -> None:
        """A request gone to its target (conn and tid None: not over Modbus TCP)."""
        if len(self._addresses) >= ADDRESSES_KEPT:
            self._addresses.clear()
        self._addresses[server, tid] = adu[0]
        self.hub.emit_threadsafe(_event("request", adu[0], adu[1], server, conn, tid, unit,
                                        adu[1:], "", None))

    def outcome(self, adu: bytes, server: str | None, sent, unit: int | None, reply: bytes | None,
                outcome: str, latency_ms: float | None) -> None:
        """The end of a transaction: the server's reply, or none.  sent: (conn, tid) of the
        request, or None when it never went out (no connection)."""
        conn, tid = sent or (None, None)
        if reply is None:
            event = _event("no reply", adu[0], adu[1], server, conn, tid, unit, b"", outcome,
                           latency_ms)
        else:
            event = _event("reply", adu[0], reply[0], server, conn, tid, unit, reply, outcome,
                           latency_ms)
        self.hub.emit_threadsafe(event)

    def table(self, adu: bytes, reply, outcome: str, latency_ms: float) -> None:
        """A request answered from the exchange table (reply None: a broadcast, or the
        master moved on)."""
        emit = self.hub.emit_threadsafe
        emit(_event("request", adu[0], adu[1], TABLE_SERVER, None, None, None, adu[1:], "",
                    None))
        if reply is None:
            emit(_event("no reply", adu[0], adu[1], TABLE_SERVER, None, None, None, b"",
                        outcome, latency_ms))
        else:
            emit(_event("reply", adu[0], reply[0], TABLE_SERVER, None, None, None, bytes(reply),
                        outcome, latency_ms))

    def late(self, server: str, conn, tid: int, unit: int, reply: bytes) -> None:
        """A server's reply to an earlier request, dropped."""
        self.hub.emit_threadsafe(_event("late", self._addresses.get((server, tid)), reply[0],
                                        server, conn, tid, unit, reply, Outcome.LATE, None))

    def ignored(self, adu: bytes) -> None:
        self.hub.emit_threadsafe(_event("ignored", adu[0], adu[1], None, None, None, None,
                                        adu[1:], Outcome.IGNORED, None))


def _event(direction: str, address: int | None, function: int, server: str | None, conn,
           tid: int | None, unit: int | None, data: bytes, outcome: str,
           latency_ms: float | None) -> TraceEvent:
    return {"time": time.time(), "mode": "master", "direction": direction,
            "address": address, "server": server,
            "peer": conn.local if conn is not None else None, "local": server,
            "remote": server,
            "tid": tid, "unit": unit, "function": function, "length": len(data),
            "pdu": data.hex(), "outcome": outcome, "latency_ms": latency_ms}
