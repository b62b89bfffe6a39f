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

log = logging.getLogger("mbgw.control")

DEFAULT_DIR = "/run/mbgw"


def default_path(name: str = "mbgw") -> str:
    """systemd's RuntimeDirectory when it set one, else /run/mbgw."""
    directory = os.environ.get("RUNTIME_DIRECTORY", DEFAULT_DIR).split(":")[0]
    return os.path.join(directory, f"{name}.sock")


class ControlServer:
    def __init__(self, path: str, commands: dict) -> None:
        self.path = path
        self._commands = commands      # name -> callable(request dict) -> reply dict
        self._server: asyncio.base_events.Server | None = None

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
        self._server = await asyncio.start_unix_server(self._handle, self.path)
        os.chmod(self.path, 0o660)

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            line = await reader.readline()
            request = json.loads(line or b"{}")
            name = request.get("command")
            request["uid"] = _peer_uid(writer)
            if name == "trace":
                await self._commands["trace"](request, reader, writer)
                return
            handler = self._commands.get(name)
            try:
                reply = handler(request) if handler else {"error": f"unknown command {name!r}"}
            except Exception:   # a bug must cost one command, and say so, not a silent EOF
                log.exception("control command %r failed", name)
                reply = {"error": f"internal error in {name} (see the daemon's log)"}
            writer.write(json.dumps(reply).encode() + b"\n")
            await writer.drain()
        except (ConnectionError, json.JSONDecodeError, AttributeError) as err:
            log.debug("control connection: %s", err)
        finally:
            writer.close()


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
