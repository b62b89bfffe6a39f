"""What a daemon hands the web console (WebHooks), as it does the control socket."""
import dataclasses
from collections.abc import Awaitable, Callable

from mbgw.ops.events import EventRing
from mbgw.ops.reload import Outcome


@dataclasses.dataclass
class WebHooks:
    """What a daemon hands the console, as it does the control socket."""
    commands: dict                 # the control commands: name -> callable(request) -> reply
    trace: object                  # the trace hub (mbgw.ops.trace.TraceHub)
    config_file: str | None        # the configuration file, None: settings from the command line
    reload: Callable[[], Awaitable[Outcome]]   # apply the file again: the SIGHUP path
    events: EventRing | None = None            # the last audit events (the Events page)
    restart: Callable[[str], Awaitable[str]] | None = None   # ops.restart.Restart
