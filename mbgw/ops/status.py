"""What the running daemon reports through the control socket: the commands both modes share
(stats reset, trace); each mode's status and close are in mbgw.slave.status and
mbgw.master.status."""
import asyncio
import json
import logging
import os
import time

from mbgw import __version__
from mbgw.audit import Kind, event, operator
from mbgw.config.lines import PRIMARY_LINE, LineConfig
from mbgw.ops.trace import NO_RAW_VIEW
from mbgw.ops.trace import filters as trace_filters

log = logging.getLogger("mbgw.control")


class DaemonStatus:
    """The control commands of a mode, over the daemon's live objects.  A mode adds status()
    and close(), and gives the counters, the device table and the trace hub."""
    mode = ""

    def __init__(self, cfg, counters, devices, trace) -> None:
        self.cfg = cfg                   # the running configuration (replaced by a reload)
        self._counters = counters
        self._devices = devices
        self._trace = trace
        if trace is not None:
            trace.line_names = self.line_names
        self._started = time.time()
        self._started_mono = time.monotonic()
        self._reset_at = self._started              # shown: "counters since"
        self._reset_mono = self._started_mono       # measured: a clock step changes nothing

    @property
    def trace_hub(self):
        """The hub the trace streams subscribe to (the control socket's, the web console's)."""
        return self._trace

    def line_names(self) -> tuple[str, ...]:
        """The daemon's lines now (a reload may add or remove some)."""
        primary = (PRIMARY_LINE,) if getattr(self.cfg, "serial_line", True) else ()
        return (*primary, *(line.name for line in getattr(self.cfg, "lines", ())))

    def commands(self) -> dict:
        return {"status": self.status, "close": self.close, "reset": self.reset,
                "trace": self.trace}

    def status(self, request: dict) -> dict:
        raise NotImplementedError

    def close(self, request: dict) -> dict:
        raise NotImplementedError

    @staticmethod
    def close_table_client(server, request: dict) -> dict:
        """close for the table server's clients (master and transparent modes); server: its
        close_client(id, who)."""
        client_id = request.get("client")
        if not isinstance(client_id, int) or isinstance(client_id, bool):
            return {"error": "close needs a client id"}
        if server.close_client(client_id, operator(request.get("uid"))):
            return {"ok": True}
        return {"error": f"no client {client_id}"}

    def summary(self) -> str:
        """One line for `systemctl status` (sd_notify STATUS=)."""
        raise NotImplementedError

    def _common(self) -> dict:
        """What every mode's status starts with."""
        s = self.cfg.serial
        demotion = getattr(self.cfg, "demotion", None)
        return {"mode": self.mode, "version": __version__, "pid": os.getpid(),
                "location": self.cfg.location,
                **({"demotion": {"down_after": demotion.down_after,
                                 "probe_interval_ms": demotion.probe_interval_ms}}
                   if demotion is not None else {}),
                "started": self._started,
                "uptime_s": round(time.monotonic() - self._started_mono, 3),
                "serial": {"device": s.device, "protocol": s.protocol, "baudrate": s.baudrate,
                           "format": str(s.format), "interface": s.wiring}}

    def trace_header(self) -> dict:
        """The first line of a trace stream."""
        return {"mode": self.mode, "lines": list(self.line_names())}

    def reset(self, request: dict) -> dict:
        self._counters.reset()
        self._devices.reset()
        self._reset_at, self._reset_mono = time.time(), time.monotonic()
        event(log, Kind.COUNTERS_RESET, "counters reset by the operator (%s)",
              operator(request.get("uid")), user=operator(request.get("uid")))
        return {"ok": True}

    async def trace(self, request: dict, reader: asyncio.StreamReader,
                    writer: asyncio.StreamWriter) -> None:
        hub = self._trace
        try:
            wanted = trace_filters(request.get("filters") or {}, hub.line_names())
        except ValueError as err:
            writer.write(json.dumps({"error": str(err)}).encode() + b"\n")
            await writer.drain()
            return
        raw = bool(request.get("raw"))
        if raw and not hub.raw_view:
            writer.write(json.dumps({"error": NO_RAW_VIEW % self.mode}).encode() + b"\n")
            await writer.drain()
            return
        queue = hub.subscribe(raw, wanted)
        log.info("%strace started (%s)", "raw " if raw else "", operator(request.get("uid")))
        gone = asyncio.ensure_future(until_closed(reader))   # the client closing ends it
        try:
            writer.write(json.dumps(self.trace_header()).encode() + b"\n")
            while not gone.done():
                getter = asyncio.ensure_future(queue.get())
                await asyncio.wait({getter, gone}, return_when=asyncio.FIRST_COMPLETED)
                if not getter.done():
                    getter.cancel()
                    break
                writer.write(json.dumps(getter.result()).encode() + b"\n")
                await writer.drain()
        except ConnectionError:
            pass
        finally:
            gone.cancel()
            dropped = hub.unsubscribe(queue)
            log.info("trace ended%s", f"; {dropped} events dropped for a slow reader"
                     if dropped else "")


async def until_closed(reader: asyncio.StreamReader) -> None:
    """Until the client closes its end; what it sends meanwhile is read and dropped, never
    kept."""
    while await reader.read(4096):
        pass


def settings_row(line: LineConfig) -> dict:
    """A line's settings as status shows them (the console's page of a line): where its
    device is, how the bytes go, and the timing of a line where mbgw is the master."""
    s = line.serial
    if line.remote is not None:
        where = {"connect": line.remote.url, "connect_delay_ms": line.connect_delay_ms,
                 "pause_ms": s.interframe_ms}
    else:
        where = {"device": s.device, "protocol": s.protocol, "baudrate": s.baudrate,
                 "format": str(s.format), "interface": s.wiring, "silence_ms": s.silence_ms,
                 "interframe_silence_ms": s.interframe_ms}
    if not line.is_target:
        return where
    return {**where, "stout_ms": s.stout_ms, "retries": line.retries,
            "down_after": line.demotion.down_after,
            "probe_interval_ms": line.demotion.probe_interval_ms,
            "cache": line.cache.text if line.cache is not None else "off"}


def line_row(name: str, device: str, mode: str, state: str, counters: dict,
             devices: list[dict], cache: dict | None = None,
             settings: dict | None = None, state_since: float | None = None) -> dict:
    """One line as `mbgw status` shows it: its name, device, mode and state, the three
    counters the table shows, all its counters and its devices (each naming the line), the
    time the line was busy (busy_ms) and its settings where the caller gives them; a
    line whose cache has served or missed: its figures by unit and the ages it served
    (mbgw.routing.cache.ReadCache.status)."""
    for row in devices:
        row["line"] = name
    busy_ns = counters.pop("line_busy_ns", None)
    row = {"name": name, "device": device, "mode": mode, "state": state,
           "requests": counters["requests"], "replies": counters["replies"],
           "timeouts": counters["timeouts"], "counters": counters, "devices": devices}
    if cache is not None and cache["units"]:
        row["cache"] = cache
    if settings is not None:
        row["settings"] = settings
    if state_since is not None:
        row["state_since"] = state_since
    if busy_ns is not None:     # the console's share of the line busy, between two looks
        row["busy_ms"] = busy_ns // 1_000_000
    return row
