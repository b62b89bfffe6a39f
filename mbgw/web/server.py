"""The web console's HTTP server on the daemon's asyncio loop (aiohttp): the site started,
restarted when a reload changes [web], closed at stop; the session, CSRF and role checks
every request passes; the bounds of a request's body; the static pages.  Its connections are
admitted and timed by mbgw.web.gate."""
import asyncio
import dataclasses
import logging
import ssl
from pathlib import Path

from aiohttp import web

from mbgw.config.model import WebConfig
from mbgw.errors import ListenError
from mbgw.net.address import parse_host_port
from mbgw.ops.limits import WarnLimit
from mbgw.ops.reload import ReloadReport
from mbgw.web import admin_api, api, api_io, routes_api
from mbgw.web.auth import COOKIE, CSRF_HEADER, LoginLimit, Sessions
from mbgw.web.gate import Gate
from mbgw.web.hooks import WebHooks

log = logging.getLogger("mbgw.web")

STATIC = Path(__file__).parent / "static"
SHUTDOWN_S = 1.0                # open requests (a trace stream) get this long at stop
OPEN_PATHS = frozenset({"/api/login"})          # no session needed
ANY_ROLE_POSTS = frozenset({"/api/logout"})     # state-changing, but not the gateway's state
ADMIN_READS = frozenset({"/api/config/file"})   # the file holds the password hashes
HSTS = "max-age=31536000"       # https-only: a year
HEADERS = {"X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY",
           "Referrer-Policy": "no-referrer",
           "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'"}


class WebServer:
    def __init__(self, hooks: WebHooks) -> None:
        self.hooks = hooks
        self.cfg = WebConfig()
        self.sessions = Sessions()
        self.limit = LoginLimit()
        self.warn = WarnLimit(log)
        self.names: list[str] = []
        self._runner: web.AppRunner | None = None
        self.gate: Gate | None = None                 # the runner's connections
        self._retiring: set[asyncio.Task] = set()     # sites closing after a move

    @property
    def https(self) -> bool:
        return self.cfg.https

    @property
    def passwords(self) -> dict:
        return {"admin": self.cfg.admin_password, "user": self.cfg.user_password}

    async def start(self, cfg: WebConfig) -> None:
        """Listen as cfg says (nothing when listen is off); raises ListenError."""
        self.cfg = cfg
        if cfg.listen is None:
            return
        host, port = parse_host_port(cfg.listen, example="127.0.0.1:8080")
        context = _ssl_context(cfg)
        runner = web.AppRunner(self._app(), access_log=None)
        await runner.setup()
        gate = Gate(runner, context, cfg.https_only, cfg.request_timeout_ms / 1000)
        try:
            self.names = gate.listen(host, port)
        except OSError as err:
            await runner.cleanup()
            raise ListenError("--web", cfg.listen, err) from None
        self._runner, self.gate = runner, gate
        scheme = "https" if cfg.https else "http"
        log.info("web console on %s", ", ".join(f"{scheme}://{n}/" for n in self.names))

    async def reconfigure(self, cfg: WebConfig, report: ReloadReport | None = None) -> None:
        """A reload: new passwords end the sessions; a new address or certificate restarts
        the site.  The requests under way are still answered (the one that asked for the
        reload waits for its outcome); a new address that cannot be listened on goes to the
        report, and the console stays where it was."""
        if cfg == self.cfg:
            return
        if (cfg.admin_password, cfg.user_password) != (self.cfg.admin_password,
                                                        self.cfg.user_password):
            self.sessions.clear()
            log.info("web console: passwords changed, sessions ended")
        if (cfg.listen, cfg.cert, cfg.key, cfg.https_only) == \
                (self.cfg.listen, self.cfg.cert, self.cfg.key, self.cfg.https_only):
            self.cfg = cfg
            if self.gate is not None:
                self.gate.timeout_s = cfg.request_timeout_ms / 1000
            return
        old, running = self.cfg, (self._runner, self.gate)
        self._stop_listening()
        try:
            await self.start(cfg)
        except OSError as err:       # ListenError and ssl.SSLError included
            why = await self._back_to(old, f"web console off: {err}", err)
            self.cfg = self.cfg if self._runner is not None \
                else dataclasses.replace(cfg, listen=None)      # off: the next reload tries
            if report is None:
                log.error("%s", why)
            else:
                report.refuse("web", why)
        self._retire(running)
        if cfg.listen is None:
            log.info("web console off")

    async def _back_to(self, old: WebConfig, why: str, err: Exception) -> str:
        """The console where it was, after a new address failed; why it is not moved."""
        if old.listen is None:
            return why
        try:
            await self.start(old)
        except OSError:       # ListenError and ssl.SSLError included
            return why
        return f"{err}; the console stays on {old.listen}"

    def _stop_listening(self) -> None:
        """Accept no more connections; the open ones are served until the runner retires."""
        if self.gate is not None:
            self.gate.stop_listening()
        self._runner, self.gate, self.names = None, None, []

    def _retire(self, running: tuple) -> None:
        """A site that no longer listens closed in the background: its requests under way
        (SHUTDOWN_S at most) end first."""
        runner, gate = running
        if runner is not None:
            task = asyncio.ensure_future(_cleanup(runner, gate))
            self._retiring.add(task)
            task.add_done_callback(self._retiring.discard)

    async def close(self) -> None:
        if self._runner is not None:
            running = self._runner, self.gate
            self._stop_listening()
            await _cleanup(*running)
        if self._retiring:
            await asyncio.gather(*self._retiring, return_exceptions=True)

    def _app(self) -> web.Application:
        app = web.Application(middlewares=[_track, _guard], client_max_size=api_io.MAX_BODY)
        app["server"] = self
        app["hooks"] = self.hooks
        app.add_routes(api.routes())
        app.add_routes(admin_api.routes())
        app.add_routes(routes_api.routes())
        app.add_routes([web.get("/", _index), web.static("/static", STATIC)])
        app.on_response_prepare.append(_headers)   # type: ignore[arg-type]  # aiohttp 3.8's stub
        return app


async def _cleanup(runner: web.AppRunner, gate: Gate | None) -> None:
    if gate is not None:
        await gate.close(SHUTDOWN_S)
    await runner.cleanup()


async def start_web(cfg: WebConfig, hooks: WebHooks) -> WebServer:
    """The console (idle while [web] listen is off, so that a reload can turn it on);
    raises ListenError when it cannot listen."""
    server = WebServer(hooks)
    await server.start(cfg)
    return server


@web.middleware
async def _track(request: web.Request, handler):
    """The gate knows which connections have a request under way (never closed for room), and
    a body over its bound is refused before a byte of it is read."""
    server: WebServer = request.app["server"]
    gate = server.gate
    if gate is not None:
        gate.began(request.protocol)
    try:
        limit = api_io.body_limit(request)
        if request.content_length is not None and request.content_length > limit:
            return api_io.error(413, f"the body is over {limit} bytes")
        return await handler(request)
    finally:
        if gate is not None:
            gate.ended(request.protocol)


@web.middleware
async def _guard(request: web.Request, handler):
    """The API's rules: a live session (401), and for every state-changing request the
    session's CSRF token (403) and the admin role (403)."""
    path = request.path
    if not path.startswith("/api/") or path in OPEN_PATHS:
        return await handler(request)
    server: WebServer = request.app["server"]
    session = server.sessions.get(request.cookies.get(COOKIE))
    if session is None:
        return api_io.error(401, "not logged in, or the session has expired")
    request["session"] = session
    changing = request.method not in ("GET", "HEAD", "OPTIONS")
    if changing and request.headers.get(CSRF_HEADER) != session.csrf:
        log.warning("web: %s %s refused: missing or wrong CSRF token (%s)", request.method,
                    path, api_io.who(request))
        return api_io.error(403, f"missing or wrong {CSRF_HEADER}")
    if session.role != "admin" and ((changing and path not in ANY_ROLE_POSTS)
                                    or path in ADMIN_READS):
        return api_io.error(403, "the user role may only read; log in as admin")
    return await handler(request)


async def _headers(request: web.Request, response: web.StreamResponse) -> None:
    response.headers.update(HEADERS)
    if request.app["server"].cfg.https_only:
        response.headers["Strict-Transport-Security"] = HSTS
    if request.path.startswith("/api/"):
        response.headers.setdefault("Cache-Control", "no-store")


async def _index(request: web.Request) -> web.FileResponse:
    return web.FileResponse(STATIC / "index.html")


def _ssl_context(cfg: WebConfig) -> ssl.SSLContext | None:
    if cfg.cert is None or cfg.key is None:
        return None
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(cfg.cert, cfg.key)
    return context

