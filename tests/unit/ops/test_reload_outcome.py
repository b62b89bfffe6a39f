"""A reload's one outcome (mbgw.ops.reload): applied, partly applied with what and why, or
refused with the reason; logged once, truthfully, and handed to whoever asked (SIGHUP or the
web console).  The mode's live objects are a recording apply()."""
import asyncio
import dataclasses
import logging

import pytest

from mbgw.errors import ConfigFileError
from mbgw.ops.reload import Outcome, Reloads


@dataclasses.dataclass(frozen=True)
class Settings:
    stout: int = 600
    tls: str = "a.pem"
    metrics: str | None = None


class Holder:
    def __init__(self, cfg: Settings) -> None:
        self.cfg = cfg


def reloads(file, apply=None):
    """Reloads of a daemon running Settings(), whose file is file() (raising: refused)."""
    holder = Holder(Settings())
    applied = []

    async def default_apply(new, report):
        applied.append(new)
    r = Reloads(holder, file)
    r.apply = apply or default_apply
    return r, holder, applied


def outcome_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "mbgw"
            and ("reload" in r.getMessage())]


@pytest.fixture(autouse=True)
def _logs(caplog):
    caplog.set_level(logging.INFO, logger="mbgw")
    logging.getLogger("mbgw").propagate = True


def test_a_change_applied_is_said_once(caplog):
    r, holder, applied = reloads(lambda: Settings(stout=700))
    outcome = asyncio.run(r.run())
    assert outcome == Outcome("applied", ("stout",))
    assert outcome.message() == "configuration reloaded: stout changed"
    assert holder.cfg.stout == 700 and applied == [Settings(stout=700)]
    assert outcome_lines(caplog) == ["configuration reloaded: stout changed"]


def test_a_refused_file_applies_nothing_and_says_why_once(caplog):
    def file():
        raise ConfigFileError("/etc/mbgw/mbgw.toml", ["tls.key: x.key does not match tls.cert"])
    r, holder, applied = reloads(file)
    outcome = asyncio.run(r.run())
    assert outcome.status == "refused" and not outcome.applied and applied == []
    assert holder.cfg == Settings()
    assert outcome.as_dict()["reason"] == \
        "/etc/mbgw/mbgw.toml: tls.key: x.key does not match tls.cert"
    assert outcome_lines(caplog) == ["reload refused, the running configuration stays: "
                                     "/etc/mbgw/mbgw.toml: tls.key: x.key does not match "
                                     "tls.cert"]
    assert caplog.records[-1].levelno == logging.ERROR


def test_what_apply_could_not_do_is_not_said_to_be_changed(caplog):
    """No "not applied" followed by "reloaded: tls changed": one line, and the running
    configuration keeps the old TLS, so that the next reload tries it again."""
    async def apply(new, report):
        report.refuse("tls", "cannot listen on tls-port 802 (Address already in use)")
    r, holder, _ = reloads(lambda: Settings(stout=700, tls="b.pem"), apply)
    outcome = asyncio.run(r.run())
    assert outcome.status == "partly applied" and not outcome.applied
    assert outcome.changed == ("stout",)
    assert outcome.message() == ("configuration reloaded: stout changed; not applied: tls: "
                                 "cannot listen on tls-port 802 (Address already in use)")
    assert holder.cfg == Settings(stout=700, tls="a.pem")
    assert outcome_lines(caplog) == [outcome.message()]
    assert caplog.records[-1].levelno == logging.WARNING


def test_a_setting_for_the_restart_is_named_with_why():
    r, holder, applied = reloads(lambda: Settings(metrics=":9502"))
    outcome = asyncio.run(r.run())
    assert outcome.status == "partly applied" and outcome.changed == ()
    assert outcome.message() == ("configuration reloaded: nothing changed; not applied: "
                                 "metrics: takes effect at restart (systemctl restart mbgw)")
    assert applied == [Settings()] and holder.cfg == Settings()


def test_nothing_changed_is_applied():
    r, holder, applied = reloads(Settings)
    outcome = asyncio.run(r.run())
    assert outcome == Outcome("applied") and applied == []
    assert outcome.message() == "configuration reloaded: nothing changed"


def test_reloads_run_one_at_a_time():
    """The web console's and a SIGHUP's: the second reads the file after the first is in
    force."""
    files = iter([Settings(stout=700), Settings(stout=800)])
    seen = []

    async def apply(new, report):
        seen.append(("start", new.stout))
        await asyncio.sleep(0)
        seen.append(("end", new.stout))
    r, holder, _ = reloads(lambda: next(files), apply)

    async def both():
        return await asyncio.gather(r.run(), r.run())
    first, second = asyncio.run(both())
    assert seen == [("start", 700), ("end", 700), ("start", 800), ("end", 800)]
    assert (first.changed, second.changed) == (("stout",), ("stout",))
    assert holder.cfg.stout == 800


def test_without_a_file_a_reload_is_refused():
    r = Reloads(Holder(Settings()), None)
    r.apply = None
    outcome = asyncio.run(r.run())
    assert outcome.status == "refused" and "command line" in outcome.reason


def test_a_bug_while_applying_is_an_outcome_too(caplog):
    """The console's request gets an answer, the log says it (with the traceback), and the
    running configuration stays the old one, so that the next reload tries it all again."""
    async def apply(new, report):
        raise RuntimeError("boom")
    r, holder, _ = reloads(lambda: Settings(stout=700), apply)
    outcome = asyncio.run(r.run())
    assert outcome.status == "partly applied" and outcome.changed == ()
    assert "failed while applying (RuntimeError('boom'))" in outcome.message()
    assert holder.cfg == Settings()
    assert any(r.exc_info for r in caplog.records)
