"""The JSON API under /api: every page's data and action.  Each handler reads or acts
through the daemon's control commands (the same dicts `mbgw status`, `mbgw table` and `mbgw
scenario` get) and its trace hub; none of it runs on the line thread.  The session, CSRF and
role checks are the server's middleware (mbgw.web.server)."""
import asyncio
import json
import logging

from aiohttp import web

from mbgw.audit import Kind, event
from mbgw.ops.trace import FILTER_KEYS, NO_RAW_VIEW
from mbgw.ops.trace import filters as trace_filters
from mbgw.web import config_api
from mbgw.web.api_io import answer, body, command, config_path, error, read, reloaded, who
from mbgw.web.auth import COOKIE, ROLES
from mbgw.web.passwords import verify

log = logging.getLogger("mbgw.web")

KEEPALIVE_S = 15.0                 # an SSE comment this often while nothing happens
GONE_CHECK_S = 1.0                 # aiohttp 3.8 does not end a handler whose client has gone


def routes() -> list:
    return [
        web.post("/api/login", login), web.post("/api/logout", logout),
        web.get("/api/session", session),
        web.get("/api/status", status), web.get("/api/clients", clients),
        web.post(r"/api/clients/{id:\d+}/close", close_client),
        web.get("/api/devices", devices),
        web.get("/api/scenarios", scenarios),
        web.post("/api/scenarios/test", test_scenario),
        web.get("/api/scenarios/config", scenario_tables),
        web.post("/api/scenarios/config", edit_scenarios),
        web.post("/api/scenarios/{name}/{action:enable|disable}", enable_scenario),
        web.get("/api/table", table_read), web.post("/api/table", table_write),
        web.get("/api/stats", stats), web.post("/api/stats/reset", stats_reset),
        web.get("/api/trace", trace),
        web.get("/api/config", config_show), web.post("/api/config", config_set),
        web.get("/api/config/file", config_download),
        web.post("/api/config/file", config_upload),
    ]


# --- login -----------------------------------------------------------------------------------

async def login(request: web.Request) -> web.Response:
    server = request.app["server"]
    address = request.remote or "?"
    wait = server.limit.attempt(address)       # counted before anything is awaited
    if wait:
        server.warn.warn(address, "login", "web login from %s refused: too many failed "
                         "logins, %d s to wait", address, wait, kind=Kind.LOGIN_FAILED,
                         client=address, reason="too many failed logins")
        return web.json_response({"error": f"too many failed logins: try again in {wait} s"},
                                 status=429, headers={"Retry-After": str(wait)})
    data = await body(request)
    role, password = data.get("user"), data.get("password")
    stored = server.passwords.get(role) if role in ROLES else None
    ok = isinstance(password, str) and stored is not None and \
        await asyncio.to_thread(verify, password, stored)
    if not ok:
        event(log, Kind.LOGIN_FAILED, "web login failed for %r from %s", role, address,
              client=address, user=role, reason="wrong user or password")
        return error(401, "wrong user or password")
    server.limit.succeeded(address)
    server.sessions.close(request.cookies.get(COOKIE))     # a new session id, never the old
    token, new = server.sessions.open(role)
    event(log, Kind.LOGIN_OK, "web login: %s from %s", role, address, client=address,
          user=role)
    response = web.json_response({"role": new.role, "csrf": new.csrf})
    response.set_cookie(COOKIE, token, httponly=True, samesite="Strict", path="/",
                        secure=server.https or None)
    return response


async def logout(request: web.Request) -> web.Response:
    request.app["server"].sessions.close(request.cookies.get(COOKIE))
    response = web.json_response({"ok": True})
    response.del_cookie(COOKIE, path="/")
    return response


async def session(request: web.Request) -> web.Response:
    s = request["session"]
    return web.json_response({"role": s.role, "csrf": s.csrf})


# --- what the daemon reports -----------------------------------------------------------------

async def status(request: web.Request) -> web.Response:
    return web.json_response(await command(request, "status"))


async def clients(request: web.Request) -> web.Response:
    """Every Modbus TCP client: the listeners' (slave mode; a master-mode daemon's TCP face,
    its "tcp_clients") and the table server's (master and transparent modes)."""
    reply = await command(request, "status")
    return web.json_response({"clients": [*reply.get("tcp_clients", []),
                                          *reply.get("clients", [])]})


async def close_client(request: web.Request) -> web.Response:
    reply = await command(request, "close", {"client": int(request.match_info["id"])})
    if reply and str(reply.get("error", "")).startswith("no client"):
        return error(404, reply["error"])
    return answer(reply, "no clients to close in this mode")


def every_device(status: dict) -> list[dict]:
    """Every line's devices, each naming its line (the status's "devices" are line
    serial's)."""
    lines = status.get("lines")
    if not lines:
        return status.get("devices", [])
    return [device for line in lines for device in line.get("devices", ())]


async def devices(request: web.Request) -> web.Response:
    reply = await command(request, "status")
    return web.json_response({"devices": every_device(reply)})


async def stats(request: web.Request) -> web.Response:
    reply = await command(request, "status")
    figures = {name: reply[name] for name in
               ("counters", "counters_since", "line_utilisation_pct", "line_load_pct",
                "devices", "table", "firewall", "scenarios") if name in reply}
    if reply.get("lines"):
        figures["devices"] = every_device(reply)
        figures["lines"] = {line["name"]: line.get("counters", {}) for line in reply["lines"]}
    if reply.get("servers"):
        figures["servers"] = {row["server"]: row["counters"] for row in reply["servers"]}
    return web.json_response(figures)


async def stats_reset(request: web.Request) -> web.Response:
    return answer(await command(request, "reset"), "no counters")


# --- scenarios -------------------------------------------------------------------------------

async def scenarios(request: web.Request) -> web.Response:
    reply = await command(request, "scenarios")
    return web.json_response(reply if reply is not None else {"scenarios": []})


async def enable_scenario(request: web.Request) -> web.Response:
    data = await body(request)
    name = f"scenario-{request.match_info['action']}"
    return answer(await command(request, name, {"name": request.match_info["name"],
                                                "save": data.get("save", False) is True}),
                  "no scenarios in this mode")


async def test_scenario(request: web.Request) -> web.Response:
    return answer(await command(request, "scenario-test", {"fields": await body(request)}),
                  "no scenarios in this mode")


async def scenario_tables(request: web.Request) -> web.Response:
    try:
        return web.json_response({"scenarios": config_api.scenario_tables(
            config_path(request))})
    except config_api.ConfigRefused as err:
        return _refused(err)


async def edit_scenarios(request: web.Request) -> web.Response:
    """{"remove": [NAME...], "add": [{KEY: VALUE...}...]}: the scenarios toolbox's changes,
    written at once and applied by one reload."""
    data = await body(request)
    remove, add = data.get("remove", []), data.get("add", [])
    if not isinstance(remove, list) or not all(isinstance(n, str) for n in remove) \
            or not isinstance(add, list) or not all(isinstance(f, dict) for f in add):
        return error(400, 'expected {"remove": [NAME...], "add": [{KEY: VALUE...}...]}')
    try:
        done = config_api.edit_scenarios(config_path(request), remove, add)
    except config_api.ConfigRefused as err:
        return _refused(err)
    if not done:
        return web.json_response({"ok": True, "changed": []})
    event(log, Kind.CONFIG_CHANGED, "scenarios changed from the web console (%s): %s",
          who(request), ", ".join(done), source="web", user=who(request),
          keys=", ".join(done))
    return await reloaded(request, {"changed": done})


# --- the exchange table ----------------------------------------------------------------------

async def table_read(request: web.Request) -> web.Response:
    query = request.query
    try:
        args = {"address": int(query["address"], 0), "count": int(query.get("count", "1"), 0),
                "bits": query.get("bits", "0") in ("1", "true")}
    except KeyError:
        return error(400, "table: 'address' missing")
    except ValueError as err:
        return error(400, f"table: {err}")
    return answer(await command(request, "table-read", args),
                  "the exchange table is off in this daemon")


async def table_write(request: web.Request) -> web.Response:
    data = await body(request)
    return answer(await command(request, "table-write", {"address": data.get("address"),
                                                         "values": data.get("values")}),
                  "the exchange table is off in this daemon")


# --- live traffic ----------------------------------------------------------------------------

async def trace(request: web.Request) -> web.StreamResponse:
    """Server-sent events: one trace event (mbgw.ops.trace) per `data:` line; a comment
    first, and every KEEPALIVE_S while nothing happens."""
    hub = request.app["hooks"].trace
    query = request.query
    raw = query.get("raw") in ("1", "true")
    try:
        wanted = trace_filters({key: query[key] for key in FILTER_KEYS if query.get(key)},
                               hub.line_names())
        if raw and not hub.raw_view:
            raise ValueError(NO_RAW_VIEW % "this")
    except ValueError as err:
        raise web.HTTPBadRequest(text=json.dumps({"error": str(err)}),
                                 content_type="application/json") from None
    response = web.StreamResponse(headers={"Content-Type": "text/event-stream",
                                           "Cache-Control": "no-store"})
    await response.prepare(request)
    queue = hub.subscribe(raw, wanted)
    log.info("web %strace started (%s)", "raw " if raw else "", who(request))
    quiet = 0.0
    try:
        await response.write(b": trace\n\n")
        while _connected(request):
            try:
                event = await asyncio.wait_for(queue.get(), GONE_CHECK_S)
            except asyncio.TimeoutError:
                quiet += GONE_CHECK_S
                if quiet >= KEEPALIVE_S:
                    await response.write(b": keep-alive\n\n")
                    quiet = 0.0
                continue
            quiet = 0.0
            await response.write(b"data: " + json.dumps(event).encode() + b"\n\n")
    except ConnectionError:
        pass
    finally:
        dropped = hub.unsubscribe(queue)
        log.info("web trace ended (%s)%s", who(request),
                 f"; {dropped} events dropped for a slow reader" if dropped else "")
    return response


def _connected(request: web.Request) -> bool:
    transport = request.transport
    return transport is not None and not transport.is_closing()


# --- the configuration file ------------------------------------------------------------------

def _refused(err: config_api.ConfigRefused) -> web.Response:
    return error(400, str(err), field=err.field, problems=err.problems)


async def config_show(request: web.Request) -> web.Response:
    try:
        return web.json_response(config_api.show(config_path(request)))
    except config_api.ConfigRefused as err:
        return _refused(err)


async def config_set(request: web.Request) -> web.Response:
    """One key ({"group", "key", "value"}) or several ({"changes": [{"group", "key",
    "value"}, ...]}), checked together, written once and applied by one reload."""
    data = await body(request)
    wanted = data.get("changes", [data])
    if not isinstance(wanted, list) or not wanted or not all(map(_change, wanted)):
        return error(400, 'expected {"group", "key", "value"} or {"changes": [{"group", '
                          '"key", "value"}, ...]}')
    try:
        changed = config_api.set_values(config_path(request),
                                        [(w["group"], w["key"], w["value"]) for w in wanted])
    except config_api.ConfigRefused as err:
        return _refused(err)
    event(log, Kind.CONFIG_CHANGED, "configuration changed from the web console (%s): %s",
          who(request), ", ".join(changed), source="web", user=who(request),
          keys=", ".join(changed))
    return await reloaded(request, {"changed": changed})


def _change(wanted) -> bool:
    return isinstance(wanted, dict) and isinstance(wanted.get("group"), str) \
        and isinstance(wanted.get("key"), str) and wanted.get("value") is not None


async def config_download(request: web.Request) -> web.Response:
    path = config_path(request)
    try:
        text = config_api.read_file(path)
    except config_api.ConfigRefused as err:
        return _refused(err)
    return web.Response(text=text, content_type="application/toml", headers={
        "Content-Disposition": f'attachment; filename="{path.name}"'})


async def config_upload(request: web.Request) -> web.Response:
    path = config_path(request)
    try:
        text = (await read(request)).decode()
        mode = config_api.upload(path, text)
    except UnicodeDecodeError:
        return error(400, "the file is not UTF-8")
    except config_api.ConfigRefused as err:
        return _refused(err)
    event(log, Kind.CONFIG_CHANGED, "configuration file replaced from the web console (%s)",
          who(request), source="web", user=who(request), keys="the whole file")
    return await reloaded(request, {"mode": mode})
