"""What systemd sees of the gateway, started as its units start it (NOTIFY_SOCKET,
WATCHDOG_USEC, RUNTIME_DIRECTORY): WATCHDOG=1 only while the line thread turns, in both
modes; the STATUS= line of `systemctl status`; the control socket of an instance mbgw@NAME.

A wedged line thread is that one thread really stopped: the test (the gateway's parent, so
Yama allows it) seizes it with ptrace and interrupts it where it is, as a serial driver stuck
in the kernel would hold it, while the gateway's asyncio thread runs on."""
import contextlib
import ctypes
import os
import re
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.cli.options import EX_CONFIG
from mbgw.cli.table_options import persist_path
from mbgw.ops import control
from mbgw.ops.restart import EX_RESTART
from tests.harness import CHECKOUT
from tests.integration.master.rig import ask, holding_reply, identity, read_holding
from tests.modbus import Client
from tests.modbus import read_holding as read_holding_pdu
from tests.ops import status, wait_for_log

pytestmark = pytest.mark.integration

INTERVAL_S = 0.25                        # the gateway pings every WatchdogSec / 2
WATCHDOG = {"WATCHDOG_USEC": str(int(INTERVAL_S * 2 * 1_000_000))}
STOUT_MS = 1000                          # pymodbus's first answer, on a loaded host
TCPTO_MS = 100
SERVER = "127.0.7.1"
NOTIFIED_S = 10.0                        # for a notification that is due
QUIET_S = 8 * INTERVAL_S                 # a watchdog that has stopped stays silent this long
IDLE_PINGS = 12                          # 3 s: longer than a turn of the line thread may take
LOST_PINGS = 28                          # 7 s: past the reopen waits of 0.5, 1, 2 and 4 s

PTRACE_SEIZE, PTRACE_INTERRUPT, PTRACE_DETACH = 0x4206, 0x4207, 17
WALL = 0x40000000                        # waitpid's __WALL: a thread of another process
_libc = ctypes.CDLL(None, use_errno=True)
_libc.ptrace.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p]


def _ptrace(request: int, tid: int) -> None:
    if _libc.ptrace(request, tid, None, None) < 0:
        errno = ctypes.get_errno()
        raise OSError(errno, f"ptrace({request:#x}, {tid}): {os.strerror(errno)}")


@contextlib.contextmanager
def thread_stopped(pid: int, tid: int):
    """The thread tid of a child process stopped (the others run on) until the block ends.
    It is stopped inside a system call, where a Python thread has let go of the GIL: stopped
    in user space, it might hold the GIL and freeze every thread of the daemon, which is not
    what a driver stuck in the kernel does; then it is let go and stopped again."""
    for _ in range(1000):
        _ptrace(PTRACE_SEIZE, tid)
        _ptrace(PTRACE_INTERRUPT, tid)
        os.waitpid(tid, WALL)
        if not _in_user_space(pid, tid):
            break
        _ptrace(PTRACE_DETACH, tid)
    else:
        raise AssertionError(f"thread {tid} was never stopped inside a system call")
    try:
        yield
    finally:
        _ptrace(PTRACE_DETACH, tid)


def _in_user_space(pid: int, tid: int) -> bool:
    """/proc's syscall file of a stopped thread: its system call's number, or -1 outside one."""
    return Path(f"/proc/{pid}/task/{tid}/syscall").read_text().split()[0] == "-1"


def line_thread(gw) -> int:
    """The id of the gateway's line thread (named mbgw-line, see native.name_thread)."""
    tasks = Path(f"/proc/{gw.proc.pid}/task")
    found = [int(t.name) for t in tasks.iterdir()
             if (t / "comm").read_text().strip() == "mbgw-line"]
    assert len(found) == 1, [(t.name, (t / "comm").read_text()) for t in tasks.iterdir()]
    return found[0]


def notified(gw, want, what: str) -> str:
    """The first notification (after those read already) for which want(message) holds."""
    deadline = time.monotonic() + NOTIFIED_S
    seen = []
    while (left := deadline - time.monotonic()) > 0:
        message = gw.notification(left)
        if message is not None and want(message):
            return message
        seen.append(message)
    raise AssertionError(f"no {what} within {NOTIFIED_S} s; got {seen}\n{gw.log()}")


def pinged(gw, times: int = 3) -> None:
    for _ in range(times):
        notified(gw, lambda m: m == "WATCHDOG=1", "WATCHDOG=1")


def status_line(gw, text: str) -> None:
    notified(gw, lambda m: m == f"STATUS={text}", f"STATUS={text}")


def watchdog_follows_the_line_thread(gw) -> None:
    """Stop the line thread: the pings stop, the daemon says why (log, STATUS=) while its
    control socket still answers; let it go: the pings come back."""
    with thread_stopped(gw.proc.pid, line_thread(gw)):
        notified(gw, lambda m: m.startswith("STATUS=") and m.endswith("; line thread stuck"),
                 "STATUS= saying the line thread is stuck")
        deadline = time.monotonic() + QUIET_S
        while (left := deadline - time.monotonic()) > 0:
            message = gw.notification(left)
            assert message != "WATCHDOG=1", "a ping while the line thread is stopped"
        assert status(gw)["pid"] == gw.proc.pid          # the rest of the daemon is alive
        wait_for_log(gw, "the line thread has not turned for")
    pinged(gw)
    wait_for_log(gw, "the line thread turns again: watchdog pings resumed")


def test_slave_mode_pings_the_watchdog_while_its_line_thread_turns(
        pty_pair, start_peer, start_gateway):
    start_peer("pymodbus_slave.py", pty_pair.device)
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--stout", str(STOUT_MS),
                       env=WATCHDOG, keep_notify=True)
    status_line(gw, "slave mode: line up, 0 clients, 0 requests, 0 timeouts")
    pinged(gw, IDLE_PINGS)      # idle longer than a turn may take: the thread turns all the same
    client = Client(gw.port)
    try:
        # pymodbus's holding registers 0, 1 hold 100, 101
        assert client.ask(17, read_holding_pdu(0, 2)) == bytes.fromhex("03 04 0064 0065")
        status_line(gw, "slave mode: line up, 1 clients, 1 requests, 0 timeouts")
    finally:
        client.close()
    watchdog_follows_the_line_thread(gw)


def test_master_mode_pings_the_watchdog_while_its_line_thread_turns(
        pty_pair, servers_at, line, start_gateway):
    port, _ = servers_at(SERVER)
    gw = start_gateway(pty_pair.gateway, "--baudrate", "19200", "--mdbport", str(port),
                       "--tcpto", str(TCPTO_MS), "--slaveid", f"1 1 1 0 {SERVER}",
                       mode="master", listen=False, env=WATCHDOG, keep_notify=True)
    status_line(gw, "master mode: line up, 0 server connections, 0 requests, 0 timeouts")
    pinged(gw, IDLE_PINGS)
    ask(line, read_holding(1), expected=holding_reply(1, *identity(SERVER, 1)))
    status_line(gw, "master mode: line up, 1 server connections, 1 requests, 0 timeouts")
    watchdog_follows_the_line_thread(gw)


@pytest.mark.parametrize("mode", ["slave", "master"])
def test_the_watchdog_is_pinged_while_the_device_is_lost(pty_pair, start_gateway, mode):
    """Reopening a lost device is the line thread's work too: it turns once per interval
    while it waits between tries (0.5 s, then doubling up to 5 s)."""
    options = ("--slaveid", f"1 1 1 0 {SERVER}") if mode == "master" else ()
    gw = start_gateway(pty_pair.gateway, *options, mode=mode, listen=mode == "slave",
                       env=WATCHDOG, keep_notify=True)
    peers = "server connections" if mode == "master" else "clients"
    pty_pair.stop()                          # the device disappears (socat has exited)
    status_line(gw, f"{mode} mode: line down, 0 {peers}, 0 requests, 0 timeouts")
    pinged(gw, LOST_PINGS)
    assert "the line thread has not turned" not in gw.log()


def test_a_full_notify_queue_never_holds_up_the_daemon(pty_pair, start_gateway):
    """Nobody reads the notify socket (systemd busy): once its queue (10 datagrams) is full,
    the periodic pings are dropped, logged at debug, and the daemon goes on serving."""
    gw = start_gateway(pty_pair.gateway, "--log-level", "debug", env=WATCHDOG,
                       keep_notify=True)
    wait_for_log(gw, "sd_notify WATCHDOG=1: ")
    assert status(gw)["pid"] == gw.proc.pid
    pinged(gw, 20)              # the queued ones, then new ones


def test_no_watchdog_for_another_process(pty_pair, start_gateway):
    """WATCHDOG_PID names the process systemd watches: another one (a child that inherited
    the environment) must not ping."""
    gw = start_gateway(pty_pair.gateway, env={**WATCHDOG, "WATCHDOG_PID": "1"},
                       keep_notify=True)
    status_line(gw, "slave mode: line up, 0 clients, 0 requests, 0 timeouts")
    deadline = time.monotonic() + QUIET_S
    while (left := deadline - time.monotonic()) > 0:
        assert gw.notification(left) != "WATCHDOG=1"


# --- the instances' control sockets ---------------------------------------------------------

def test_instance_option_reaches_the_socket_its_unit_lays_out(monkeypatch):
    """mbgw@NAME's RuntimeDirectory= makes systemd set RUNTIME_DIRECTORY, where the daemon
    puts its socket; `-i NAME` must name that same socket."""
    unit = (CHECKOUT / "debian" / "mbgw@.service").read_text()
    runtime = re.search(r"^RuntimeDirectory=(\S+)$", unit, re.M).group(1)
    monkeypatch.setenv("RUNTIME_DIRECTORY", "/run/" + runtime.replace("%i", "ttyUSB1"))
    assert control.instance_path("ttyUSB1") == control.default_path()
    assert control.instance_path("ttyUSB1") == "/run/mbgw/ttyUSB1/mbgw.sock"


@pytest.mark.parametrize("unit, instance, table_file", [
    ("mbgw.service", None, "/var/lib/mbgw/table"),
    ("mbgw@.service", "ttyUSB1", "/var/lib/mbgw/ttyUSB1/table")])
def test_the_units_let_the_service_write_its_files_and_nothing_else(monkeypatch, unit,
                                                                    instance, table_file):
    """ProtectSystem=strict, but for its configuration directory (the console's Set and
    Upload replace the file atomically: the directory) and its state directory, where
    StateDirectory= makes systemd set STATE_DIRECTORY and the table's file goes by default."""
    text = (CHECKOUT / "debian" / unit).read_text()
    settings = re.findall(r"^(ProtectSystem|ReadWritePaths|StateDirectory)=(.*)$", text, re.M)
    assert sorted(settings) == [("ProtectSystem", "strict"), ("ReadWritePaths", "/etc/mbgw"),
                                ("StateDirectory", "mbgw/%i" if instance else "mbgw")]
    state = dict(settings)["StateDirectory"].replace("%i", instance or "")
    monkeypatch.setenv("STATE_DIRECTORY", f"/var/lib/{state}")
    assert persist_path(None) == table_file
    assert re.search(r"^ExecStart=/usr/bin/mbgw run --config /etc/mbgw/(mbgw|%i)\.toml$", text,
                     re.M)


@pytest.mark.parametrize("unit", ["mbgw.service", "mbgw@.service"])
def test_the_units_restart_on_the_console_s_status_and_not_on_a_wrong_file(unit):
    """EX_RESTART: a clean stop (no failure recorded) that systemd restarts whatever
    Restart= says; 2 and 78 are never restarted."""
    text = (CHECKOUT / "debian" / unit).read_text()
    keys = dict(re.findall(r"^(Restart\w*|SuccessExitStatus)=(.*)$", text, re.M))
    assert keys["Restart"] == "on-failure"
    assert keys["RestartForceExitStatus"].split() == [str(EX_RESTART)]
    assert keys["SuccessExitStatus"].split() == [str(EX_RESTART)]
    assert keys["RestartPreventExitStatus"].split() == ["2", str(EX_CONFIG)]


def test_instance_option_talks_to_that_daemon(pty_pair, start_gateway, tmp_path, monkeypatch):
    """status, stats reset, clients close and trace with -i NAME, against a daemon whose
    runtime directory is NAME (the harness's, under tmp_path standing for /run/mbgw)."""
    gw = start_gateway(pty_pair.gateway)
    name = Path(gw.control).parent.name
    monkeypatch.setattr(control, "DEFAULT_DIR", str(tmp_path))
    runner = CliRunner()
    result = runner.invoke(main, ["status", "--json", "-i", name])
    assert result.exit_code == 0, result.output
    assert f'"pid": {gw.proc.pid}' in result.output
    result = runner.invoke(main, ["stats", "reset", "--instance", name])
    assert (result.exit_code, result.output) == (0, "counters reset\n")
    result = runner.invoke(main, ["clients", "close", "7", "-i", name])
    assert result.exit_code == 1 and "no client 7" in result.output
    result = runner.invoke(main, ["trace", "--count", "1", "-i", "nosuch"])
    assert result.exit_code == 1
    assert f"no mbgw daemon answers on {tmp_path}/nosuch/mbgw.sock" in result.output
