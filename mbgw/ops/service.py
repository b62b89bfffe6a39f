"""What both modes' daemons share: systemd notification, the control socket and metrics
endpoint started and closed, SIGHUP reload, the stop and its last log line."""
import asyncio
import dataclasses
import logging
import os
import signal
import socket
from typing import TYPE_CHECKING

from mbgw.ops.control import ControlServer, default_path

if TYPE_CHECKING:
    from mbgw.ops.metrics import MetricsServer

log = logging.getLogger("mbgw")


def sd_notify(state: str) -> None:
    """Tell systemd (or a test) about our state, when NOTIFY_SOCKET asks for it."""
    path = os.environ.get("NOTIFY_SOCKET")
    if not path:
        return
    if path.startswith("@"):
        path = "\0" + path[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
            sock.sendto(state.encode(), path)
    except OSError as err:    # nobody listening any more: not our problem to die of
        log.debug("sd_notify %s: %s", state, err)


class ListenError(Exception):
    def __init__(self, port: int, err: OSError) -> None:
        super().__init__(f"cannot listen on port {port}: {err.strerror}")


class MetricsListenError(ListenError):
    def __init__(self, address: str, err: OSError) -> None:
        reason = os.strerror(err.errno) if err.errno else str(err)
        Exception.__init__(self, f"--metrics {address}: cannot listen there: {reason}")


def start_metrics(address: str | None, collector) -> "MetricsServer | None":
    """The --metrics endpoint (None when off) serving collector(mbgw.ops.metrics); .names are
    its listening addresses.  Raises MetricsListenError when it cannot listen.  Without
    --metrics, mbgw.ops.metrics and prometheus_client are never imported (45 ms, 3 MiB)."""
    if not address:
        return None
    from mbgw.ops import metrics as module
    metrics = module.MetricsServer(address, collector(module))
    try:
        metrics.names = metrics.start()
    except OSError as err:
        raise MetricsListenError(address, err) from None
    return metrics


async def start_control(path: str | None, commands: dict) -> ControlServer | None:
    """The control socket; None (logged) when it cannot be had: the gateway runs without."""
    control = ControlServer(path or default_path(), commands)
    try:
        await control.start()
    except OSError as err:
        log.warning("control socket %s unavailable (%s): mbgw status and trace will not "
                    "reach this daemon", control.path, err.strerror)
        return None
    return control


async def serve_until_stopped(stop: asyncio.Event, holder, reconfigure, apply,
                              control: ControlServer | None,
                              metrics: "MetricsServer | None") -> None:
    """Ready: reload on SIGHUP (see reload_on_sighup), tell systemd, wait for `stop`
    (SIGTERM, SIGINT), then tell systemd and close the operator's tools; the mode closes its
    own objects after."""
    reload_on_sighup(asyncio.get_running_loop(), holder, reconfigure, apply)
    sd_notify("READY=1")
    await stop.wait()
    sd_notify("STOPPING=1")
    log.info("stopping")
    close_tools(control, metrics)


def close_tools(control: ControlServer | None, metrics: "MetricsServer | None") -> None:
    if control is not None:
        control.close()
    if metrics is not None:
        metrics.close()


def log_stopped(counters) -> None:
    log.info("stopped; counters: %s",
             " ".join(f"{k}={v}" for k, v in counters.snapshot().items()))


RESTART_SETTINGS = ("control", "metrics")


def reload_on_sighup(loop: asyncio.AbstractEventLoop, holder, reconfigure, apply) -> None:
    """SIGHUP (systemctl reload) applies the configuration file again, in either mode.
    holder.cfg is the running configuration, replaced when a reload is applied; reconfigure()
    gives the file's settings (None: there is no file); `await apply(new)` puts them in
    force in the mode's live objects."""
    async def reload() -> None:
        sd_notify("RELOADING=1")
        try:
            new = await _reloaded(holder.cfg, reconfigure, apply)
        finally:
            sd_notify("READY=1")
        if new is not None:
            holder.cfg = new

    loop.add_signal_handler(signal.SIGHUP, lambda: asyncio.ensure_future(reload()))


async def _reloaded(cfg, reconfigure, apply):
    """Apply the configuration file again; the configuration now in force, or None when the
    file cannot be applied (the reason is logged)."""
    if reconfigure is None:
        log.warning("SIGHUP: no configuration file to reload (settings came from the "
                    "command line)")
        return None
    try:
        new = reconfigure()
    except Exception as err:      # a bad file must never stop a running gateway
        reason = err.format_message() if hasattr(err, "format_message") else str(err)
        log.error("reload refused, the running configuration stays: %s", reason)
        return None
    changed = [f"serial.{f.name}" for f in dataclasses.fields(new.serial)
               if getattr(new.serial, f.name) != getattr(cfg.serial, f.name)]
    changed += [f.name for f in dataclasses.fields(new)
                if f.name != "serial" and getattr(new, f.name) != getattr(cfg, f.name)]
    if not changed:
        log.info("configuration reloaded: nothing changed")
        return cfg
    kept = [name for name in RESTART_SETTINGS if name in changed]
    if kept:
        log.warning("%s: changes need a restart (systemctl restart mbgw)", ", ".join(kept))
        new = dataclasses.replace(new, **{name: getattr(cfg, name) for name in kept})
    await apply(new)
    log.info("configuration reloaded: %s changed", ", ".join(changed))
    return new
