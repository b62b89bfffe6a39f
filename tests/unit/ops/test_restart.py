"""The console's restart (mbgw.ops.restart): as the main process of a unit that restarts on
EX_RESTART, the daemon exits with it for systemd to start the unit again; anywhere else it
executes itself again.  systemd here is its environment, the cgroup file and a `systemctl`
that answers `show` as systemd 252's does (scripts/container-test.sh runs the real one; the
units' keys: tests/integration/ops/test_systemd.py)."""
import asyncio
import logging
import os
import sys

import pytest

from mbgw.ops import restart
from mbgw.ops.restart import EX_RESTART, Restart

WHO = "web admin@127.0.0.1"


@pytest.fixture
def execv(monkeypatch):
    """The re-executions asked, instead of done."""
    calls = []
    monkeypatch.setattr(restart.os, "execv", lambda path, argv: calls.append((path, argv)))
    monkeypatch.setattr(restart.logging, "shutdown", lambda: None)
    return calls


@pytest.fixture
def systemd(monkeypatch, tmp_path):
    """This process as the main process of mbgw@gw2.service; returns set_force(STATUSES),
    what the unit's RestartForceExitStatus= says, and the file of systemctl's arguments."""
    monkeypatch.setenv("INVOCATION_ID", "5f2b3c4d5e6f47a8b9c0d1e2f3a4b5c6")
    monkeypatch.setenv("SYSTEMD_EXEC_PID", str(os.getpid()))
    cgroup = tmp_path / "cgroup"
    cgroup.write_text("1:name=systemd:/system.slice/system-mbgw.slice/mbgw@gw2.service\n"
                      "0::/system.slice/system-mbgw.slice/mbgw@gw2.service\n")
    monkeypatch.setattr(restart, "CGROUP", cgroup)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    args = tmp_path / "systemctl-args"

    def set_force(statuses: str) -> None:
        systemctl = bin_dir / "systemctl"
        systemctl.write_text(f'#!/bin/sh\necho "$@" >> {args}\necho "{statuses}"\n')
        systemctl.chmod(0o755)
    set_force(str(EX_RESTART))
    return set_force, args


def ask(r: Restart) -> tuple[str, bool]:
    """The console's call on a serving daemon: its answer, and whether the daemon stops."""
    async def run():
        r.stop = asyncio.Event()
        how = await r(WHO)
        return how, r.stop.is_set()
    return asyncio.run(run())


def test_under_its_unit_the_daemon_exits_for_systemd_to_start_it_again(systemd, execv, caplog):
    _, args = systemd
    r = Restart()
    caplog.set_level(logging.INFO, "mbgw.service")
    assert ask(r) == ("systemd restarts mbgw@gw2.service", True)
    assert args.read_text() == "show --property=RestartForceExitStatus --value " \
                               "mbgw@gw2.service\n"
    assert [(rec.levelno, rec.getMessage()) for rec in caplog.records] == [
        (logging.INFO, f"restart asked ({WHO}): systemd restarts mbgw@gw2.service")]
    with pytest.raises(SystemExit) as stopped:
        r.finish()
    assert stopped.value.code == EX_RESTART
    assert execv == []


def test_a_unit_that_would_not_restart_on_the_status_gets_the_daemon_re_executed(systemd,
                                                                                 execv):
    set_force, _ = systemd
    set_force("")                                  # a unit of the operator's own, say
    r = Restart()
    assert ask(r) == ("the daemon stops and starts again", True)
    r.finish()
    assert execv == [(sys.executable, [sys.executable, *sys.orig_argv[1:]])]


def test_a_child_of_a_unit_s_process_is_not_its_main_process(systemd, monkeypatch, execv):
    monkeypatch.setenv("SYSTEMD_EXEC_PID", str(os.getppid()))
    assert restart.own_unit() is None
    assert ask(Restart())[0] == "the daemon stops and starts again"


def test_outside_systemd_the_daemon_executes_itself_again(monkeypatch, execv):
    monkeypatch.delenv("INVOCATION_ID", raising=False)
    r = Restart()
    r.finish()                                     # nothing asked: nothing done
    assert execv == []
    assert ask(r) == ("the daemon stops and starts again", True)
    r.finish()
    assert execv == [(sys.executable, [sys.executable, *sys.orig_argv[1:]])]


def test_a_daemon_that_does_not_serve_yet_refuses():
    with pytest.raises(OSError, match="not serving yet"):
        asyncio.run(Restart()(WHO))

