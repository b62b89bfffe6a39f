"""Live traffic for `mbgw trace`: events go to whoever subscribed over the control socket.
With nobody tracing, the only cost on the transaction path is one attribute test.  The
daemon has one hub; each line emits through its LineTrace, which names the line in the
event.  Every key an event may carry is in TraceEvent, every outcome in Outcome.

A raw subscriber (`mbgw trace --raw`) gets the lines' bursts instead (mbgw.line.raw).
While one watches, every line's raw watcher has been told to capture them; nobody
watching, no line captures anything.

Filters (a subscriber's, `filters()`): "unit", "client", "function", "scenario", "line"
(one of the daemon's line names: its events, and a serial face's requests routed to it) and
"errors" (errors only: an exception reply, a scenario's
reply that did not answer its request, no reply but to a broadcast, a late reply, noise); raw
events are filtered by line and errors only."""
import asyncio
import logging
from collections.abc import Callable, Iterable
from enum import StrEnum
from typing import Any, TypedDict


class TraceEvent(TypedDict, total=False):
    """One event of `mbgw trace` (JSON on the control socket and the console)."""
    time: float             # when it was emitted (Unix time)
    line: str | None        # the line's name ("serial" or a [[line]] name); None: no line
    #                         (answered by the table, refused by the firewall, unroutable)
    direction: str          # request, reply, no reply, late (a reply after its request
    #                         timed out, dropped), ignored (master mode: no route takes it;
    #                         a monitor line: a frame whose CRC is wrong)
    tid: int | None         # the Modbus/TCP transaction id (None: not over Modbus/TCP)
    unit: int | None        # the unit id of the Modbus/TCP exchange
    address: int | None     # master mode: the serial address the line's master asked for
    function: int
    length: int             # of the PDU
    pdu: str                # hex
    outcome: str            # an Outcome ("" for a request); a scenario's run: its kind, ok
    latency_ms: float | None
    # The two ends of the Modbus/TCP exchange as mbgw.cli.pcap writes them.  Slave mode: the
    # remote client and mbgw's listener; master mode: mbgw's own end of the upstream
    # connection and the remote server.
    peer: str | None        # the client's end
    local: str | None       # the server's end
    remote: str | None      # the far end as mbgw shows it: the client (slave mode), the
    #                         target (master mode: a server's address, "table", a line)
    client: int             # slave mode: the client's id (mbgw status)
    face: str               # the listener the client came in by: plain, tls, udp, rtu
    mode: str               # "master" in master mode, "transparent" in transparent mode
    server: str | None      # master mode: the target shown (IP:port, "table", a line)
    scenario: str           # a scenario's run: its name (and neither peer nor local)
    # A raw burst (`--raw`, mbgw.line.raw)
    raw: bool
    kind: str               # request, reply, noise, unsolicited, dropped
    bytes: str              # hex
    frame: str              # transparent mode: the frame as it went on the line, hex
    gap_us: int | None      # silence since the burst before


# What the hub passes on: a TraceEvent, or a dict built with the same keys.
Event = TraceEvent | dict[str, Any]


class Outcome(StrEnum):
    """How a request ended, in every mode (an event's "outcome")."""
    REPLY = "reply"
    DEVICE_EXCEPTION = "device exception"     # the serial device's exception reply
    SERVER_EXCEPTION = "server exception"     # the Modbus TCP server's
    TIMEOUT = "timeout"
    UNREACHABLE = "unreachable"               # no connection to the server
    BAD_REPLY = "not the answer"              # the reply with our tid does not answer it
    IGNORED = "not in the slaveid table"      # master mode: no route takes the address
    LINE_DOWN = "line down"
    DEVICE_DOWN = "device down"               # refused at once: its address is down, no probe
    LATE = "late reply, dropped"              # the reply to a request that timed out
    BROADCAST = "broadcast"
    UNROUTABLE = "unroutable"
    ERROR = "internal error"
    TABLE = "table"                           # answered from the exchange table
    FIREWALL = "firewall"                     # refused by the firewall (0x01)
    WITHDRAWN = "client gone"                 # its source closed before its turn
    CRC_ERROR = "crc error"                   # a monitor line: a frame heard that does not check
    COALESCED = "coalesced"                   # the answer of an identical read under way
    # and from memory (mbgw.routing.cache): "cached <age> ms", "stale <age> ms"


log = logging.getLogger("mbgw.trace")

# A raw trace where the line has no capture (transparent mode reads the line itself).
NO_RAW_VIEW = ("--raw: %s mode has no raw line view; mbgw trace shows each frame there in "
               "hex as it went on the line")
QUEUE_LIMIT = 10_000    # events a slow reader may lag behind before events are dropped for it
PRIMARY = "serial"      # the first line's name (mbgw.config.lines.PRIMARY_LINE)
FILTER_KEYS = ("unit", "client", "function", "scenario", "line", "errors")
_NUMBERS = {"unit": (0, 255), "client": (1, 2**31), "function": (1, 127)}


def filters(given: dict, lines: Iterable[str] = (PRIMARY,)) -> dict:
    """The filters of a trace request (keys of FILTER_KEYS; None: not set), checked against
    the daemon's line names: a ValueError names the one that is wrong and why."""
    lines = tuple(lines)
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
            if value not in lines:
                raise ValueError(f"trace: line {value!r}: {known_lines(lines)}")
            out[key] = value
        elif key == "errors":
            out[key] = bool(value)
        else:
            out[key] = str(value)
    return out


def known_lines(lines: tuple[str, ...]) -> str:
    """The daemon's lines, for an error naming a line it does not have."""
    if len(lines) == 1:
        return f"this daemon has one line, {lines[0]}"
    return f"this daemon's lines are {', '.join(lines)}"


def is_error(event: Event) -> bool:
    if event.get("raw"):
        return event.get("kind") == "noise"
    direction = event.get("direction")
    if direction == "late" or event.get("outcome") == Outcome.CRC_ERROR:
        return True
    if direction == "no reply":
        return event.get("outcome") != "broadcast"
    if direction == "reply":
        return bool(event.get("function", 0) & 0x80) or \
            (event.get("scenario") is not None and event.get("outcome") != "ok")
    return False


def matches(event: Event, wanted: dict) -> bool:
    """Whether event passes the filters (filters()'s); a request passes the errors filter
    never: its outcome is in the reply."""
    if not wanted:
        return True
    if wanted.get("errors") and not is_error(event):
        return False
    if "line" in wanted and event.get("line", PRIMARY) != wanted["line"] and \
            event.get("server") != f"line {wanted['line']}":
        return False      # neither on that line nor a serial face's request to it
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
    """The daemon's one hub: every line's events, to every subscriber."""

    def __init__(self) -> None:
        self._subscribers: dict[asyncio.Queue, _Subscriber] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self.active = False           # a subscriber wants the decoded events
        self.raw_active = False       # one wants the lines' raw bursts
        # called (on the asyncio thread) when raw_active changes: each line starts or stops
        # capturing (added by the lines' threads)
        self._raw_watchers: list[Callable[[bool], None]] = []
        # the daemon's line names now, for the "line" filter (set by the daemon's status)
        self.line_names: Callable[[], tuple[str, ...]] = lambda: (PRIMARY,)

    @property
    def raw_view(self) -> bool:
        """Whether any line can show its raw bursts (transparent mode's cannot)."""
        return bool(self._raw_watchers)

    def add_raw_watcher(self, watcher: Callable[[bool], None]) -> None:
        self._raw_watchers.append(watcher)

    def remove_raw_watcher(self, watcher: Callable[[bool], None]) -> None:
        if watcher in self._raw_watchers:
            self._raw_watchers.remove(watcher)

    def for_line(self, name: str) -> "LineTrace":
        return LineTrace(self, name)

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
            for watcher in list(self._raw_watchers):
                watcher(raw)

    def emit(self, event: Event) -> None:
        """On the asyncio loop's thread."""
        raw = bool(event.get("raw"))
        for queue, subscriber in self._subscribers.items():
            if subscriber.raw != raw or not matches(event, subscriber.filters):
                continue
            if queue.full():
                subscriber.dropped += 1
            else:
                queue.put_nowait(event)

    def emit_threadsafe(self, event: Event) -> None:
        """From another thread (the line thread), while active."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self.emit, event)


class LineTrace:
    """One line's way into the daemon's hub: what it emits carries the line's name."""
    __slots__ = ("hub", "line")

    def __init__(self, hub: TraceHub, line: str) -> None:
        self.hub = hub
        self.line = line

    @property
    def active(self) -> bool:
        return self.hub.active

    @property
    def raw_active(self) -> bool:
        return self.hub.raw_active

    def add_raw_watcher(self, watcher: Callable[[bool], None]) -> None:
        self.hub.add_raw_watcher(watcher)

    def remove_raw_watcher(self, watcher: Callable[[bool], None]) -> None:
        self.hub.remove_raw_watcher(watcher)

    def emit_threadsafe(self, event: Event) -> None:
        event["line"] = self.line
        self.hub.emit_threadsafe(event)
