"""What every handler of the JSON API shares (mbgw.web.api, admin_api, routes_api, and the
server's middleware): the request's body read within its bounds, the operator named, a
control command called, the reply or the error written, the configuration file found and,
once written, reloaded."""
import asyncio
import json
from pathlib import Path

from aiohttp import web

from mbgw.config.file import nesting

MAX_NESTING = 32                  # arrays and objects in one another in a JSON body, at most
MAX_BODY = 1_000_000              # a request's body; more is refused (413)
LOGIN_BODY = 4096                 # a login's: who needs more is not logging in


def who(request: web.Request) -> str:
    """The operator as the logs name them (the control commands' "uid")."""
    session = request.get("session")
    return f"web {session.role if session else '-'}@{request.remote}"


def error(status: int, message: str, **more) -> web.Response:
    return web.json_response({"error": message, **more}, status=status)


def body_limit(request: web.Request) -> int:
    return LOGIN_BODY if request.path == "/api/login" else MAX_BODY


async def read(request: web.Request) -> bytes:
    """The request's body, whole within request-timeout (408 raised else) and within its
    bound (413 raised as soon as it is over, a chunked body included)."""
    timeout_s = request.app["server"].cfg.request_timeout_ms / 1000
    try:
        return await asyncio.wait_for(_bounded(request, body_limit(request)), timeout_s)
    except asyncio.TimeoutError:
        raise web.HTTPRequestTimeout(text=json.dumps(
            {"error": f"the body did not come whole within {timeout_s:g} s"}),
            content_type="application/json") from None


async def _bounded(request: web.Request, limit: int) -> bytes:
    data = bytearray()
    while chunk := await request.content.read(65536):
        data += chunk
        if len(data) > limit:
            raise web.HTTPRequestEntityTooLarge(max_size=limit, actual_size=len(data))
    return bytes(data)


async def body(request: web.Request) -> dict:
    """The request's JSON object; a 400 response is raised when it is not one."""
    try:
        data = json.loads((await read(request)).decode() or "{}")
        if nesting(data) > MAX_NESTING:
            raise ValueError
    except (ValueError, RecursionError):
        raise web.HTTPBadRequest(text=json.dumps(
            {"error": f"the body is not valid JSON (nested {MAX_NESTING} deep at most)"}),
            content_type="application/json") from None
    if not isinstance(data, dict):
        raise web.HTTPBadRequest(text=json.dumps({"error": "the body must be a JSON object"}),
                                 content_type="application/json")
    return data


async def command(request: web.Request, name: str, args: dict | None = None):
    """A control command's reply dict; None when this mode has no such command."""
    handler = request.app["hooks"].commands.get(name)
    if handler is None:
        return None
    reply = handler({**(args or {}), "uid": who(request)})
    return await reply if asyncio.iscoroutine(reply) else reply


def answer(reply: dict | None, missing: str) -> web.Response:
    """A command's reply: 200, or 400 with its error; 404 when the mode lacks it."""
    if reply is None:
        return error(404, missing)
    if "error" in reply:
        return error(400, reply["error"])
    return web.json_response(reply)


def config_path(request: web.Request) -> Path:
    path = request.app["hooks"].config_file
    if path is None:
        raise web.HTTPNotFound(text=json.dumps(
            {"error": "this daemon's settings came from the command line: no configuration "
                      "file to show or change"}), content_type="application/json")
    return Path(path)


async def reloaded(request: web.Request, done: dict) -> web.Response:
    """The file is written: the daemon reloads it (as SIGHUP does), and the answer is the
    reload's outcome, as the log says it.  200 only when every change is in force; 409 when
    the file is written but the daemon refused it or put part of it in force (the running
    configuration then differs from the file)."""
    # shielded: a client that goes away (aiohttp cancels its handler) stops no reload
    outcome = await asyncio.shield(asyncio.ensure_future(request.app["hooks"].reload()))
    reply = {**done, "written": True, "reload": outcome.as_dict()}
    if outcome.applied:
        return web.json_response({"ok": True, **reply})
    return error(409, f"written, but {outcome.message()}", **reply)
