"""The web console's HTTP server on the daemon's asyncio loop (aiohttp): the site started,
restarted when a reload changes [web], closed at stop; the session, CSRF and role checks
every request passes; the static pages."""
import asyncio
import dataclasses
import logging
import ssl
from pathlib import Path

from aiohttp import web

from mbgw.config.model import WebConfig
from mbgw.ops.reload import ReloadReport
from mbgw.web import api
from mbgw.web.address import parse_listen
from mbgw.web.auth import COOKIE, CSRF_HEADER, LoginLimit, Sessions
from mbgw.web.hooks import WebHooks, WebListenError

log = logging.getLogger("mbgw.web")

STATIC = Path(__file__).parent / "static"
SHUTDOWN_S = 1.0                # open requests (a trace stream) get this long at stop
OPEN_PATHS = frozenset({"/api/login"})          # no session needed
ANY_ROLE_POSTS = frozenset({"/api/logout"})     # state-changing, but not the gateway's state
ADMIN_READS = frozenset({"/api/config/file"})   # the file holds the password hashes
HEADERS = {"X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY",
           "Referrer-Policy": "no-referrer",
           "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'"}


class WebServer:
    def __init__(self, hooks: WebHooks) -> None:
        self.hooks = hooks
        self.cfg = WebConfig()
        self.sessions = Sessions()
        self.limit = LoginLimit()
        self.names: list[str] = []
        self._runner: web.AppRunner | None = None
        self._retiring: set[asyncio.Task] = set()     # sites closing after a move

    @property
    def https(self) -> bool:
        return self.cfg.https

    @property
    def passwords(self) -> dict:
        return {"admin": self.cfg.admin_password, "user": self.cfg.user_password}

    async def start(self, cfg: WebConfig) -> None:
        """Listen as cfg says (nothing when listen is off); raises WebListenError."""
        self.cfg = cfg
        if cfg.listen is None:
            return
        host, port = parse_listen(cfg.listen)
        runner = web.AppRunner(self._app(), access_log=None)
        await runner.setup()
        site = web.TCPSite(runner, host, port, ssl_context=_ssl_context(cfg),
                           shutdown_timeout=SHUTDOWN_S)
        try:
            await site.start()
        except OSError as err:
            await runner.cleanup()
            raise WebListenError(cfg.listen, err) from None
        self._runner = runner
        self.names = _names(runner)
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
        if (cfg.listen, cfg.cert, cfg.key) == (self.cfg.listen, self.cfg.cert, self.cfg.key):
            self.cfg = cfg
            return
        old, running = self.cfg, self._runner
        self._stop_listening()
        try:
            await self.start(cfg)
        except (WebListenError, OSError, ssl.SSLError) as err:
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
        except (WebListenError, OSError, ssl.SSLError):
            return why
        return f"{err}; the console stays on {old.listen}"

    def _stop_listening(self) -> None:
        """Accept no more connections; the open ones are served until the runner retires."""
        if self._runner is not None:
            for site in self._runner.sites:
                server = getattr(site, "_server", None)
                if server is not None:
                    server.close()
            self._runner, self.names = None, []

    def _retire(self, runner: web.AppRunner | None) -> None:
        """A site that no longer listens closed in the background: its requests under way
        (SHUTDOWN_S at most) end first."""
        if runner is not None:
            task = asyncio.ensure_future(runner.cleanup())
            self._retiring.add(task)
            task.add_done_callback(self._retiring.discard)

    async def close(self) -> None:
        if self._runner is not None:
            runner, self._runner, self.names = self._runner, None, []
            await runner.cleanup()
        if self._retiring:
            await asyncio.gather(*self._retiring, return_exceptions=True)

    def _app(self) -> web.Application:
        app = web.Application(middlewares=[_guard], client_max_size=1024 * 1024)
        app["server"] = self
        app["hooks"] = self.hooks
        app.add_routes(api.routes())
        app.add_routes([web.get("/", _index), web.static("/static", STATIC)])
        app.on_response_prepare.append(_headers)   # type: ignore[arg-type]  # aiohttp 3.8's stub
        return app


async def start_web(cfg: WebConfig, hooks: WebHooks) -> WebServer:
    """The console (idle while [web] listen is off, so that a reload can turn it on);
    raises WebListenError when it cannot listen."""
    server = WebServer(hooks)
    await server.start(cfg)
    return server


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
        return api.error(401, "not logged in, or the session has expired")
    request["session"] = session
    changing = request.method not in ("GET", "HEAD", "OPTIONS")
    if changing and request.headers.get(CSRF_HEADER) != session.csrf:
        log.warning("web: %s %s refused: missing or wrong CSRF token (%s)", request.method,
                    path, api.who(request))
        return api.error(403, f"missing or wrong {CSRF_HEADER}")
    if session.role != "admin" and ((changing and path not in ANY_ROLE_POSTS)
                                    or path in ADMIN_READS):
        return api.error(403, "the user role may only read; log in as admin")
    return await handler(request)


async def _headers(request: web.Request, response: web.StreamResponse) -> None:
    response.headers.update(HEADERS)
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


def _names(runner: web.AppRunner) -> list[str]:
    names = []
    for site in runner.sites:
        server = getattr(site, "_server", None)
        for sock in getattr(server, "sockets", None) or ():
            host, port = sock.getsockname()[:2]
            names.append(f"[{host}]:{port}" if ":" in host else f"{host}:{port}")
    return names
