"""Live traffic for `mbgw trace`: events go to whoever subscribed over the control socket.
With nobody tracing, the only cost on the transaction path is one attribute test.

An event is a dict: "time", "direction" (request, reply, no reply, late: a reply after its
request timed out, dropped; master mode also has ignored), "tid", "unit", "function",
"length", "pdu" (hex), "outcome", "latency_ms", and the two ends of the Modbus/TCP exchange
as mbgw.cli.pcap writes them: "peer" the client's address,
"local" the server's.  In slave mode those are the remote client and mbgw's listener (plus
"client", its id); in master mode mbgw's own end of the upstream connection and the remote
server (plus "mode": "master", "address": the serial address, "server": the server shown).
A scenario's run has "scenario" (its name) and neither "peer" nor "local".

A raw subscriber (`mbgw trace --raw`) gets the line's bursts instead (mbgw.line.raw): "raw":
true, "time", "kind" (request, reply, noise, unsolicited), "bytes" (hex), "length",
"gap_us" (silence since the burst before), "line".  While one watches, `on_raw_watch(True)`
has asked the line to capture them; nobody watching, the line captures nothing.

Filters (a subscriber's, `filters()`): "unit", "client", "function", "scenario", "line"
(the one line is "serial") and "errors" (errors only: an exception reply, a scenario's reply
that did not answer its request, no reply but to a broadcast, a late reply, noise); raw events are
filtered by line and errors only."""
import asyncio
import logging
from collections.abc import Callable

log = logging.getLogger("mbgw.trace")

# A raw trace where the line has no capture (transparent mode reads the line itself).
NO_RAW_VIEW = ("--raw: %s mode has no raw line view; mbgw trace shows each frame there in "
               "hex as it went on the line")
QUEUE_LIMIT = 10_000    # events a slow reader may lag behind before events are dropped for it
LINES = ("serial",)     # the lines a --line filter may name
FILTER_KEYS = ("unit", "client", "function", "scenario", "line", "errors")
_NUMBERS = {"unit": (0, 255), "client": (1, 2**31), "function": (1, 127)}


def filters(given: dict) -> dict:
    """The filters of a trace request (keys of FILTER_KEYS; None: not set), checked: a
    ValueError names the one that is wrong and why."""
    out: dict = {}
    for key, value in given.items():
        if value is None or value is False:
            continue
        if key not in FILTER_KEYS:
            raise ValueError(f"trace: unknown filter {key!r} (known: {', '.join(FILTER_KEYS)})")
        if key in _NUMBERS:
            low, high = _NUMBERS[key]
            try:
                number = int(value, 0) if isinstance(value, str) else int(value)
            except (TypeError, ValueError):
                raise ValueError(f"trace: {key} {value!r}: expected a number") from None
            if not low <= number <= high:
                raise ValueError(f"trace: {key} {number}: expected {low}..{high}")
            out[key] = number
        elif key == "line":
            if value not in LINES:
                raise ValueError(f"trace: line {value!r}: this daemon has one line, "
                                 f"{' '.join(LINES)}")
            out[key] = value
        elif key == "errors":
            out[key] = bool(value)
        else:
            out[key] = str(value)
    return out


def is_error(event: dict) -> bool:
    if event.get("raw"):
        return event.get("kind") == "noise"
    direction = event.get("direction")
    if direction == "late":
        return True
    if direction == "no reply":
        return event.get("outcome") != "broadcast"
    if direction == "reply":
        return bool(event.get("function", 0) & 0x80) or \
            (event.get("scenario") is not None and event.get("outcome") != "ok")
    return False


def matches(event: dict, wanted: dict) -> bool:
    """Whether event passes the filters (filters()'s); a request passes the errors filter
    never: its outcome is in the reply."""
    if not wanted:
        return True
    if wanted.get("errors") and not is_error(event):
        return False
    if "line" in wanted and event.get("line", "serial") != wanted["line"]:
        return False
    if event.get("raw"):
        return True
    if "scenario" in wanted and event.get("scenario") != wanted["scenario"]:
        return False
    if "client" in wanted and event.get("client") != wanted["client"]:
        return False
    if "unit" in wanted and event.get("unit") != wanted["unit"] and \
            event.get("address") != wanted["unit"]:
        return False
    if "function" in wanted and (event.get("function", 0) & 0x7F) != wanted["function"]:
        return False
    return True


class _Subscriber:
    __slots__ = ("raw", "filters", "dropped")

    def __init__(self, raw: bool, wanted: dict) -> None:
        self.raw = raw
        self.filters = wanted
        self.dropped = 0


class TraceHub:
    def __init__(self) -> None:
        self._subscribers: dict[asyncio.Queue, _Subscriber] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self.active = False           # a subscriber wants the decoded events
        self.raw_active = False       # one wants the line's raw bursts
        # called (on the asyncio thread) when raw_active changes: the line starts or stops
        # capturing (set by the line's owner)
        self.on_raw_watch: Callable[[bool], None] | None = None

    def subscribe(self, raw: bool = False, wanted: dict | None = None) -> asyncio.Queue:
        queue: asyncio.Queue = asyncio.Queue(QUEUE_LIMIT)
        self._loop = asyncio.get_running_loop()
        self._subscribers[queue] = _Subscriber(raw, wanted or {})
        self._update()
        return queue

    def unsubscribe(self, queue: asyncio.Queue) -> int:
        """Returns the number of events dropped for this subscriber."""
        subscriber = self._subscribers.pop(queue, None)
        self._update()
        return subscriber.dropped if subscriber is not None else 0

    def _update(self) -> None:
        self.active = any(not s.raw for s in self._subscribers.values())
        raw = any(s.raw for s in self._subscribers.values())
        if raw != self.raw_active:
            self.raw_active = raw
            if self.on_raw_watch is not None:
                self.on_raw_watch(raw)

    def emit(self, event: dict) -> None:
        """On the asyncio loop's thread."""
        raw = bool(event.get("raw"))
        for queue, subscriber in self._subscribers.items():
            if subscriber.raw != raw or not matches(event, subscriber.filters):
                continue
            if queue.full():
                subscriber.dropped += 1
            else:
                queue.put_nowait(event)

    def emit_threadsafe(self, event: dict) -> None:
        """From another thread (the line thread), while active."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.emit, event)
