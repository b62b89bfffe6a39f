"""Live traffic for `mbgw trace`: events go to whoever subscribed over the control socket.
With nobody tracing, the only cost on the transaction path is one attribute test.

An event is a dict: "time", "direction" (request, reply, no reply, late: a reply after its
request timed out, dropped; master mode also has ignored), "tid", "unit", "function",
"length", "pdu" (hex), "outcome", "latency_ms", and the two ends of the Modbus/TCP exchange
as mbgw.cli.pcap writes them: "peer" the client's address,
"local" the server's.  In slave mode those are the remote client and mbgw's listener (plus
"client", its id); in master mode mbgw's own end of the upstream connection and the remote
server (plus "mode": "master", "address": the serial address, "server": the server shown)."""
import asyncio
import logging

log = logging.getLogger("mbgw.trace")

QUEUE_LIMIT = 10_000    # events a slow reader may lag behind before events are dropped for it


class TraceHub:
    def __init__(self) -> None:
        self._subscribers: dict[asyncio.Queue, list[int]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self.active = False

    def subscribe(self) -> asyncio.Queue:
        queue: asyncio.Queue = asyncio.Queue(QUEUE_LIMIT)
        self._loop = asyncio.get_running_loop()
        self._subscribers[queue] = [0]
        self.active = True
        return queue

    def unsubscribe(self, queue: asyncio.Queue) -> int:
        """Returns the number of events dropped for this subscriber."""
        dropped = self._subscribers.pop(queue, [0])[0]
        self.active = bool(self._subscribers)
        return dropped

    def emit(self, event: dict) -> None:
        """On the asyncio loop's thread."""
        for queue, dropped in self._subscribers.items():
            if queue.full():
                dropped[0] += 1
            else:
                queue.put_nowait(event)

    def emit_threadsafe(self, event: dict) -> None:
        """From another thread (master mode's line thread), while active."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.emit, event)
