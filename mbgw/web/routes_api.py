"""The Lines page's route editing: the file's [[route]] tables read, and all of them replaced
at once (checked as check-config does, written once, applied by one reload).  Changing them
is the admin's (the server's middleware checks the role)."""
import logging

from aiohttp import web

from mbgw.audit import Kind, event
from mbgw.web import config_api
from mbgw.web.api_io import body, config_path, error, reloaded, who

log = logging.getLogger("mbgw.web")


def routes() -> list:
    return [web.get("/api/routes", route_tables), web.post("/api/routes", set_routes)]


async def route_tables(request: web.Request) -> web.Response:
    try:
        return web.json_response({"routes": config_api.route_tables(config_path(request))})
    except config_api.ConfigRefused as err:
        return error(400, str(err), problems=err.problems)


async def set_routes(request: web.Request) -> web.Response:
    """{"routes": [{KEY: VALUE...}...]}: every [[route]] of the file, in order."""
    data = await body(request)
    tables = data.get("routes")
    if not isinstance(tables, list) or not all(isinstance(r, dict) for r in tables):
        return error(400, 'expected {"routes": [{KEY: VALUE...}...]}')
    try:
        config_api.set_routes(config_path(request), tables)
    except config_api.ConfigRefused as err:
        return error(400, str(err), field=err.field, problems=err.problems)
    event(log, Kind.CONFIG_CHANGED, "routes changed from the web console (%s): %d routes",
          who(request), len(tables), source="web", user=who(request), keys="route")
    return await reloaded(request, {"changed": ["route"]})
