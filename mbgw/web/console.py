"""The console as a daemon holds it: started with the loop, reconfigured by a reload,
closed at stop.  aiohttp (100 ms to import) is imported only once [web] listen is on."""
import logging
from typing import TYPE_CHECKING

from mbgw.config.model import WebConfig
from mbgw.ops.reload import ReloadReport
from mbgw.web.hooks import WebHooks

if TYPE_CHECKING:
    from mbgw.web.server import WebServer

log = logging.getLogger("mbgw.web")


class Console:
    def __init__(self, hooks: WebHooks) -> None:
        self._hooks = hooks
        self.server: "WebServer | None" = None

    async def start(self, cfg: WebConfig) -> None:
        """Raises ListenError (mbgw.errors) when it cannot listen."""
        if cfg.listen is None:
            return
        from mbgw.web.server import start_web
        self.server = await start_web(cfg, self._hooks)

    async def reconfigure(self, cfg: WebConfig, report: ReloadReport | None = None) -> None:
        """A reload's new [web] settings (None: the start's); a console that cannot start is
        told to the reload's report (logged at start), the gateway runs on."""
        if self.server is not None:
            await self.server.reconfigure(cfg, report)
            return
        try:
            await self.start(cfg)
        except OSError as err:       # ListenError and ssl.SSLError included
            if report is None:
                log.error("web console off: %s", err)
            else:
                report.refuse("web", f"web console off: {err}")

    async def close(self) -> None:
        if self.server is not None:
            await self.server.close()


async def start_console(cfg: WebConfig, hooks: WebHooks) -> Console:
    """The console of a daemon; one that cannot listen is logged and the gateway runs
    without it (as without its control socket), a reload may bring it up."""
    console = Console(hooks)
    await console.reconfigure(cfg)
    return console
