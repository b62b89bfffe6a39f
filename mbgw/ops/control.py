"""The local control socket: `mbgw status`, `clients close`, `stats reset` and `trace` talk
to the running daemon through it.  One JSON request per connection, one JSON line back (or a
stream of lines for trace).  Only root and the service's group may connect: the socket is
mode 0660 (group: the daemon's group)."""
import asyncio
import errno
import json
import logging
import os
import socket
import struct

from mbgw.errors import MbgwError
from mbgw.net.ratelimit import RateLimitedLog
from mbgw.ops.limits import WarnLimit, share

log = logging.getLogger("mbgw.control")

DEFAULT_DIR = "/run/mbgw"
MAX_REQUEST = 64 * 1024          # one request line; status replies are far larger than any request
REQUEST_TIMEOUT_S = 10.0         # a client that connects and says nothing is not kept
BAD_REQUEST_LOG_INTERVAL_S = 60.0
MAX_CONNECTIONS = 32             # at once (a trace is one for as long as it runs) ...
PER_USER = share(MAX_CONNECTIONS)    # ... of which one uid holds at most this many


class BadRequest(MbgwError):
    """A control request that cannot be served: the client is told why, in one JSON line."""


def parse_request(line: bytes) -> dict:
    """One request line to its JSON object; raises BadRequest naming what is wrong."""
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError:
        raise BadRequest("request is not UTF-8") from None
    try:
        request = json.loads(text or "{}")
    except (ValueError, RecursionError):
        raise BadRequest("request is not valid JSON") from None
    if not isinstance(request, dict):
        raise BadRequest("request must be a JSON object")
    if not isinstance(request.get("command"), str):
        raise BadRequest('request needs "command": a string')
    return request


def default_path(name: str = "mbgw") -> str:
    """systemd's RuntimeDirectory when it set one, else /run/mbgw."""
    directory = os.environ.get("RUNTIME_DIRECTORY", DEFAULT_DIR).split(":")[0]
    return os.path.join(directory, f"{name}.sock")


def instance_path(instance: str) -> str:
    """The socket of the service instance mbgw@NAME, whose RuntimeDirectory= is mbgw/%i."""
    return os.path.join(DEFAULT_DIR, instance, "mbgw.sock")


class ControlServer:
    def __init__(self, path: str, commands: dict) -> None:
        self.path = path
        self._commands = commands      # name -> callable(request dict) -> reply dict
        self._server: asyncio.base_events.Server | None = None
        self._bad_requests = RateLimitedLog(BAD_REQUEST_LOG_INTERVAL_S)
        self._open: dict[int, int] = {}        # connections by uid
        self._warn = WarnLimit(log)

    async def start(self) -> None:
        directory = os.path.dirname(self.path) or "."
        os.makedirs(directory, mode=0o755, exist_ok=True)
        if os.path.exists(self.path):
            try:
                connect(self.path, 1.0).close()
            except OSError:
                os.unlink(self.path)      # left by a daemon that did not stop cleanly
            else:
                raise OSError(errno.EADDRINUSE, "another mbgw daemon is using it")
        self._server = await asyncio.start_unix_server(self._handle, self.path,
                                                       limit=MAX_REQUEST)
        os.chmod(self.path, 0o660)

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        uid = _peer_uid(writer)
        held = self._open.get(uid, 0)
        if held >= PER_USER or sum(self._open.values()) >= MAX_CONNECTIONS:
            self._warn.warn(str(uid), "full", "control socket: a connection of uid %s refused: "
                            "%d open (at most %d, %d a user)", uid, sum(self._open.values()),
                            MAX_CONNECTIONS, PER_USER)
            writer.close()
            return
        self._open[uid] = held + 1
        try:
            await self._serve(reader, writer, uid)
        finally:
            self._open[uid] -= 1
            if not self._open[uid]:
                del self._open[uid]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                     uid: int) -> None:
        try:
            try:
                line = await _read_request(reader)
                if not line:    # connected and closed: a second daemon's probe (start())
                    log.debug("control connection closed without a request")
                    return
                request = parse_request(line)
            except BadRequest as err:
                left_out = self._bad_requests.due()
                if left_out is not None:
                    more = f" ({left_out} more since the last warning)" if left_out else ""
                    log.warning("control socket: bad request refused: %s%s", err, more)
                await _reply(writer, {"error": str(err)})
                return
            name = request["command"]
            request["uid"] = uid
            if name == "trace":
                await self._commands["trace"](request, reader, writer)
                return
            handler = self._commands.get(name)
            try:
                reply = handler(request) if handler else {"error": f"unknown command {name!r}"}
                if asyncio.iscoroutine(reply):   # a command that waits (scenario-test)
                    reply = await reply
            except Exception:   # a bug must cost one command, and say so, not a silent EOF
                log.exception("control command %r failed", name)
                reply = {"error": f"internal error in {name} (see the daemon's log)"}
            await _reply(writer, reply)
        except (ConnectionError, TimeoutError) as err:
            log.debug("control connection: %s", err)
        finally:
            writer.close()


async def _read_request(reader: asyncio.StreamReader) -> bytes:
    """The request line; raises BadRequest when it is over MAX_REQUEST bytes."""
    try:
        return await asyncio.wait_for(reader.readline(), REQUEST_TIMEOUT_S)
    except ValueError:            # over the stream's limit
        raise BadRequest(f"request longer than {MAX_REQUEST} bytes") from None


async def _reply(writer: asyncio.StreamWriter, reply: dict) -> None:
    writer.write(json.dumps(reply).encode() + b"\n")
    await writer.drain()


def _peer_uid(writer: asyncio.StreamWriter) -> int:
    sock = writer.get_extra_info("socket")
    creds = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    return struct.unpack("3i", creds)[1]


def call(path: str, request: dict, timeout: float = 5.0) -> dict:
    """Client side: one command, one reply."""
    with connect(path, timeout) as sock:
        sock.sendall(json.dumps(request).encode() + b"\n")
        data = b""
        while not data.endswith(b"\n"):
            chunk = sock.recv(65536)
            if not chunk:
                break
            data += chunk
    return json.loads(data)


def connect(path: str, timeout: float | None = 5.0) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    try:
        sock.connect(path)
    except OSError:
        sock.close()
        raise
    return sock
