"""What a daemon hands the web console (WebHooks), as it does the control socket."""
import dataclasses
import os
from collections.abc import Awaitable, Callable

from mbgw.ops.reload import Outcome
from mbgw.ops.service import ListenError


@dataclasses.dataclass
class WebHooks:
    """What a daemon hands the console, as it does the control socket."""
    commands: dict                 # the control commands: name -> callable(request) -> reply
    trace: object                  # the trace hub (mbgw.ops.trace.TraceHub)
    config_file: str | None        # the configuration file, None: settings from the command line
    reload: Callable[[], Awaitable[Outcome]]   # apply the file again: the SIGHUP path


class WebListenError(ListenError):
    def __init__(self, address: str, err: OSError) -> None:
        reason = os.strerror(err.errno) if err.errno else str(err)
        Exception.__init__(self, f"--web {address}: cannot listen there: {reason}")
