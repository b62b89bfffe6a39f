"""Live traffic for `mbgw trace`: events go to whoever subscribed over the control socket.
With nobody tracing, the only cost on the transaction path is one attribute test."""
import asyncio
import logging

log = logging.getLogger("mbgw.trace")

QUEUE_LIMIT = 10_000    # events a slow reader may lag behind before events are dropped for it


class TraceHub:
    def __init__(self) -> None:
        self._subscribers: dict[asyncio.Queue, list[int]] = {}
        self.active = False

    def subscribe(self) -> asyncio.Queue:
        queue: asyncio.Queue = asyncio.Queue(QUEUE_LIMIT)
        self._subscribers[queue] = [0]
        self.active = True
        return queue

    def unsubscribe(self, queue: asyncio.Queue) -> int:
        """Returns the number of events dropped for this subscriber."""
        dropped = self._subscribers.pop(queue, [0])[0]
        self.active = bool(self._subscribers)
        return dropped

    def emit(self, event: dict) -> None:
        for queue, dropped in self._subscribers.items():
            if queue.full():
                dropped[0] += 1
            else:
                queue.put_nowait(event)
