"""A reload, in every mode: SIGHUP (systemctl reload) and the web console's Set and Upload
apply the configuration file again, one at a time, and each reload has one outcome, logged
once and handed to whoever asked:

- refused: the file does not pass the checks of `mbgw run` (the reason names the key);
  nothing is applied, the running configuration stays;
- applied: every change is in force (or nothing changed);
- partly applied: what could not be put in force (a port another program holds, a
  setting that takes effect at restart) is named with why; the rest is in force.

The mode's apply(new, report) puts the settings in force in its live objects and tells
`report` (ReloadReport) what it could not, instead of logging it: the outcome says it."""
import asyncio
import dataclasses
import logging
import signal
from collections.abc import Awaitable, Callable

from mbgw.audit import Kind, event
from mbgw.ops.notify import sd_notify

log = logging.getLogger("mbgw")

RESTART_SETTINGS = ("control", "metrics")
GROUPED_SETTINGS = ("serial", "demotion")     # a change is named by the setting inside


class ReloadReport:
    """What a reload's apply could not put in force: setting (the settings' field, e.g.
    "tls") -> why."""

    def __init__(self) -> None:
        self.not_applied: dict[str, str] = {}

    def refuse(self, setting: str, why: str) -> None:
        """`setting` stays as it was: why."""
        self.not_applied.setdefault(setting, why)

    def at_restart(self, setting: str) -> None:
        self.refuse(setting, "takes effect at restart (systemctl restart mbgw)")


@dataclasses.dataclass(frozen=True)
class Outcome:
    """A reload's result, as the log line and the web console's answer say it."""
    status: str                     # "applied", "partly applied" or "refused"
    changed: tuple = ()             # the settings now in force that changed
    not_applied: tuple = ()         # (setting, why) of the changes not in force
    reason: str = ""                # refused: why

    @property
    def applied(self) -> bool:
        return self.status == "applied"

    def message(self) -> str:
        if self.status == "refused":
            return f"reload refused, the running configuration stays: {self.reason}"
        text = f"configuration reloaded: {', '.join(self.changed)} changed" if self.changed \
            else "configuration reloaded: nothing changed"
        if self.not_applied:
            text += "; not applied: " + "; ".join(f"{s}: {why}" for s, why in self.not_applied)
        return text

    def as_dict(self) -> dict:
        return {"status": self.status, "message": self.message(),
                "changed": list(self.changed),
                "not_applied": {setting: why for setting, why in self.not_applied},
                **({"reason": self.reason} if self.reason else {})}


class Reloads:
    """The daemon's reloads: holder.cfg is the running configuration, replaced by what a
    reload puts in force; reconfigure() gives the file's settings, checked (None: there is no
    file; it raises when the file is refused); `await apply(new, report)` puts them in force.
    apply is set once the mode's live objects exist (the web console, started before, holds
    run already)."""

    def __init__(self, holder, reconfigure: Callable | None) -> None:
        self.holder = holder
        self.reconfigure = reconfigure
        self.apply: Callable[..., Awaitable[None]] | None = None
        self._one_at_a_time = asyncio.Lock()

    def on_sighup(self, loop: asyncio.AbstractEventLoop) -> None:
        loop.add_signal_handler(signal.SIGHUP, lambda: asyncio.ensure_future(self.run()))

    async def run(self) -> Outcome:
        """Apply the file again; the outcome, logged once."""
        async with self._one_at_a_time:
            sd_notify("RELOADING=1")
            try:
                outcome = await self._reload()
            finally:
                sd_notify("READY=1")
        if outcome.status == "refused":
            log.error("%s", outcome.message())
        elif outcome.changed:
            event(log, Kind.CONFIG_CHANGED, "%s", outcome.message(), source="sighup",
                  keys=", ".join(outcome.changed),
                  level=logging.WARNING if outcome.not_applied else None)
        elif outcome.not_applied:
            log.warning("%s", outcome.message())
        else:
            log.info("%s", outcome.message())
        return outcome

    async def _reload(self) -> Outcome:
        if self.reconfigure is None or self.apply is None:
            return Outcome("refused", reason="no configuration file to reload (the settings "
                                             "came from the command line)")
        cfg = self.holder.cfg
        try:
            new = self.reconfigure()
        except Exception as err:      # a bad file must never stop a running gateway
            reason = err.format_message() if hasattr(err, "format_message") else str(err)
            return Outcome("refused", reason=reason)
        changed = changes(cfg, new)
        if not changed:
            return Outcome("applied")
        report = ReloadReport()
        for name in RESTART_SETTINGS:
            if name in changed:
                report.at_restart(name)
        new = _keeping(new, cfg, report)
        try:
            await self.apply(new, report)
        except Exception as err:      # a bug: what is in force is unknown, the next reload
            log.exception("reload: applying the new configuration failed")    # tries all
            return Outcome("partly applied", (), (("reload", f"failed while applying ({err!r}):"
                                                   " part of it may be in force"),))
        new = _keeping(new, cfg, report)
        self.holder.cfg = new
        refused = tuple(report.not_applied.items())
        done = tuple(c for c in changed if c.split(".")[0] not in report.not_applied)
        return Outcome("partly applied" if refused else "applied", done, refused)


def changes(cfg, new) -> list[str]:
    """The settings that differ: a grouped setting's by the field inside ("serial.stout_ms"),
    the others by name ("tls")."""
    changed = [f"{group}.{f.name}" for group in GROUPED_SETTINGS if hasattr(new, group)
               for f in dataclasses.fields(getattr(new, group))
               if getattr(getattr(new, group), f.name) != getattr(getattr(cfg, group), f.name)]
    changed += [f.name for f in dataclasses.fields(new) if f.name not in GROUPED_SETTINGS
                and getattr(new, f.name) != getattr(cfg, f.name)]
    return changed


def _keeping(new, cfg, report: ReloadReport):
    """new, but the running value of each setting not applied: the configuration in force,
    so that the next reload tries them again."""
    kept = {name: getattr(cfg, name) for name in report.not_applied
            if any(f.name == name for f in dataclasses.fields(new))}
    return dataclasses.replace(new, **kept) if kept else new
