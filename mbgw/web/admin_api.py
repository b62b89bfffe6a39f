"""The Administration and Events pages' API: change a password, reload, restart, factory
reset, what the machine is, and the last events.  Admin only but for the reads (the
server's middleware checks the role)."""
import asyncio
import logging
import time

from aiohttp import web

from mbgw import __version__
from mbgw.audit import Kind, event
from mbgw.errors import ConfigError
from mbgw.web import config_api, system_info
from mbgw.web.api_io import body, command, config_path, error, reloaded, who
from mbgw.web.auth import ROLES
from mbgw.web.passwords import MIN_LENGTH, hash_password, verify

log = logging.getLogger("mbgw.web")


def routes() -> list:
    return [
        web.get("/api/events", events), web.get("/api/system", system),
        web.post("/api/password", password), web.post("/api/reload", reload),
        web.post("/api/restart", restart), web.post("/api/factory-reset", factory_reset),
        web.get("/api/firewall", firewall), web.post("/api/firewall", set_firewall),
    ]


async def events(request: web.Request) -> web.Response:
    ring = request.app["hooks"].events
    return web.json_response({"events": ring.newest_first() if ring is not None else []})


async def system(request: web.Request) -> web.Response:
    status = await command(request, "status") or {}
    path = request.app["hooks"].config_file
    return web.json_response({
        "host": system_info.host_name(), "version": __version__, "mode": status.get("mode"),
        "uptime_s": status.get("uptime_s"), "started": status.get("started"),
        "now": time.time(), "serial_ports": await asyncio.to_thread(system_info.serial_ports),
        "file": None if path is None else await asyncio.to_thread(
            system_info.file_facts, config_path(request))})


async def password(request: web.Request) -> web.Response:
    """{"role", "current", "new", "again"}: current is the logged-in admin's own password."""
    data = await body(request)
    role, current, new, again = (data.get(k) for k in ("role", "current", "new", "again"))
    if role not in ROLES or not isinstance(current, str) or not isinstance(new, str) \
            or not isinstance(again, str):
        return error(400, 'expected {"role": "admin"|"user", "current", "new", "again"}')
    path = config_path(request)
    stored = request.app["server"].passwords.get(request["session"].role)
    if stored is None or not await asyncio.to_thread(verify, current, stored):
        event(log, Kind.LOGIN_FAILED, "web password change refused: wrong current password "
              "(%s)", who(request), client=request.remote, user=who(request),
              reason="wrong current password")
        return error(403, "the current password is wrong", field="current")
    if new != again:
        return error(400, "the two new passwords differ", field="again")
    if len(new) < MIN_LENGTH:
        return error(400, f"the new password is too short: at least {MIN_LENGTH} characters",
                     field="new")
    try:
        hashed = await asyncio.to_thread(hash_password, new)
        config_api.set_password(path, role, hashed)
    except ConfigError as err:
        return error(400, str(err), field="new")
    except config_api.ConfigRefused as err:
        return error(400, str(err), problems=err.problems)
    event(log, Kind.CONFIG_CHANGED, "web console: the %s password changed (%s)", role,
          who(request), source="web", user=who(request), keys=f"web.{role}-password")
    return await reloaded(request, {"changed": [f"web.{role}-password"]})


async def reload(request: web.Request) -> web.Response:
    log.info("reload asked from the web console (%s)", who(request))
    return await reloaded(request, {})


async def restart(request: web.Request) -> web.Response:
    restarter = request.app["hooks"].restart
    if restarter is None:
        return error(404, "this daemon cannot restart itself")
    try:
        how = await restarter(who(request))
    except OSError as err:
        return error(500, f"the restart failed: {err}")
    return web.json_response({"ok": True, "how": how})


async def factory_reset(request: web.Request) -> web.Response:
    """{"confirm": true}: the shipped file in place of this one, then a reload."""
    data = await body(request)
    if data.get("confirm") is not True:
        return error(400, 'a factory reset needs {"confirm": true}')
    path = config_path(request)
    try:
        await asyncio.to_thread(config_api.factory_reset, path)
    except config_api.ConfigRefused as err:
        return error(400, str(err))
    event(log, Kind.CONFIG_CHANGED, "configuration reset to the factory defaults from the "
          "web console (%s)", who(request), source="web", user=who(request),
          keys="the whole file")
    return await reloaded(request, {"factory_reset": True})


async def firewall(request: web.Request) -> web.Response:
    """The file's rules and default, and each rule's refusals since the counters' reset."""
    try:
        tables = config_api.firewall_tables(config_path(request))
    except config_api.ConfigRefused as err:
        return error(400, str(err), problems=err.problems)
    status = await command(request, "status") or {}
    return web.json_response({**tables, "report": status.get("firewall")})


async def set_firewall(request: web.Request) -> web.Response:
    """{"default": "allow"|"deny", "rules": [{KEY: VALUE...}...]}: every rule, in order."""
    data = await body(request)
    default, rules = data.get("default"), data.get("rules")
    if not isinstance(default, str) or not isinstance(rules, list) \
            or not all(isinstance(r, dict) for r in rules):
        return error(400, 'expected {"default": "allow"|"deny", "rules": [{KEY: VALUE}...]}')
    try:
        config_api.set_firewall(config_path(request), default, rules)
    except config_api.ConfigRefused as err:
        return error(400, str(err), problems=err.problems)
    event(log, Kind.CONFIG_CHANGED, "firewall changed from the web console (%s): default %s, "
          "%d rules", who(request), default, len(rules), source="web", user=who(request),
          keys="firewall")
    return await reloaded(request, {"changed": ["firewall"]})
