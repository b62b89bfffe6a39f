"""Test harness: socat pty pairs, the gateway as a real subprocess, peers as subprocesses.
Readiness is always an event (a line printed, a datagram received), never a sleep."""
import contextlib
import itertools
import os
import random
import select
import selectors
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

from tests.modbus import REPLY_S

PEERS = Path(__file__).parent / "peers"
CHECKOUT = Path(__file__).resolve().parent.parent
READY_TIMEOUT_S = 15.0


def factory(make, end):
    """A fixture's body, `yield from factory(make, end)`: the test gets a function that calls
    make(*args, **kwargs) and returns what it made; after the test, end(thing) for each."""
    made = []

    def make_one(*args, **kwargs):
        thing = make(*args, **kwargs)
        made.append(thing)
        return thing

    yield make_one
    for thing in made:
        end(thing)


# The ports the tests' gateways and peers listen on: below the kernel's ephemeral range (32768
# up), so that no connection made meanwhile takes one between free_port() and the listener's
# bind, and a block of them for each pytest-xdist worker, so that two workers never pick the
# same one.
PORTS = range(20000, 32768)


def _block() -> range:
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
    size = len(PORTS) // workers
    return PORTS[worker * size:(worker + 1) * size]


_BLOCK = _block()
# from a random start: another run of the tests at the same time most likely walks other ports
_turn = itertools.count(random.randrange(len(_BLOCK)))


def free_port(kind: socket.SocketKind = socket.SOCK_STREAM) -> int:
    """The next port of this worker's block that nothing listens on (kind SOCK_DGRAM: that
    no UDP socket is bound to either)."""
    for _ in _BLOCK:
        port = _BLOCK[next(_turn) % len(_BLOCK)]
        try:
            for each in {socket.SOCK_STREAM, kind}:
                with socket.socket(socket.AF_INET, each) as s:
                    s.bind(("127.0.0.1", port))
        except OSError:
            continue
        return port
    raise RuntimeError(f"no free port in {_BLOCK}")


def idle_connections(port: int, count: int) -> list[socket.socket]:
    """count connections to port that never send a byte (those the peer refuses included)."""
    opened = []
    for _ in range(count):
        sock = socket.socket()
        sock.setblocking(False)
        try:
            sock.connect(("127.0.0.1", port))
        except BlockingIOError:
            pass
        opened.append(sock)
    return opened


def _read_lines_until(proc: subprocess.Popen, stream, want, timeout: float) -> list[str]:
    """Read lines from stream until want(lines) is true; fail on exit or timeout.
    Reads the descriptor itself: a buffered reader would hide lines from select."""
    lines: list[str] = []
    pending = b""
    fd = stream.fileno()
    sel = selectors.DefaultSelector()
    sel.register(fd, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout
    try:
        while not want(lines):
            left = deadline - time.monotonic()
            if left <= 0 or not sel.select(left):
                raise TimeoutError(f"{proc.args[0]} not ready; said: {lines}")
            chunk = os.read(fd, 4096)
            if not chunk:
                raise RuntimeError(f"{proc.args} exited ({proc.wait()}); said: {lines}")
            *complete, pending = (pending + chunk).split(b"\n")
            lines.extend(line.decode(errors="replace") for line in complete)
    finally:
        sel.close()
    return lines


def stop(proc: subprocess.Popen, sig=signal.SIGTERM) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def read_pty(fd: int, n: int, timeout: float = REPLY_S) -> bytes:
    """Up to n bytes from fd (a pty's end), whatever came within timeout."""
    deadline = time.monotonic() + timeout
    data = b""
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            break
        data += os.read(fd, n - len(data))
    return data


class PtyPair:
    """Two linked pseudo-terminals from socat: `gateway` for mbgw, `device` for the peer."""

    def __init__(self, directory: Path) -> None:
        self.gateway = str(directory / "ttyGW")
        self.device = str(directory / "ttyDEV")
        self.proc = None
        self.start()

    def start(self) -> None:
        self.proc = subprocess.Popen(
            ["socat", "-d", "-d", f"pty,raw,echo=0,link={self.gateway}",
             f"pty,raw,echo=0,link={self.device}"],
            stderr=subprocess.PIPE, text=True)
        # socat logs "starting data transfer loop" once both ptys and links exist
        try:
            _read_lines_until(self.proc, self.proc.stderr,
                              lambda ls: any("starting data transfer loop" in row for row in ls),
                              READY_TIMEOUT_S)
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        stop(self.proc)


class Gateway:
    """`python -m mbgw slave ...` on 127.0.0.1:port, ready when it sends READY=1."""

    def __init__(self, directory: Path, device: str | None, *args: str, port: int | None = None,
                 mode: str = "slave", listen: bool = True, env: dict | None = None,
                 keep_notify: bool = False, program: tuple[str, ...] = ("-m", "mbgw")) -> None:
        """listen=False: no --bind/--mdbport (master mode, where --mdbport is the remote
        servers' port and is among args); port then only names the log and notify files.
        env: more environment variables.  keep_notify: the notify socket stays open after
        READY=1, for notification(); a test that keeps it must read it (see notification).
        program: what python runs (a test's own wrapper of mbgw's command line).  device
        None: no --device (a file whose [[line]]s define the lines, [serial] left out)."""
        self.port = port or free_port()
        self.log_path = directory / f"mbgw-{self.port}.log"
        notify_path = str(directory / f"notify-{self.port}")
        notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        notify.bind(notify_path)
        # The daemon's control socket goes where systemd's RuntimeDirectory= would put it
        runtime = directory / f"run-{self.port}"
        self.control = str(runtime / "mbgw.sock")
        env = dict(os.environ, NOTIFY_SOCKET=notify_path, RUNTIME_DIRECTORY=str(runtime),
                   **(env or {}))
        network = ["--bind", "127.0.0.1", "--mdbport", str(self.port)] if listen else []
        serial = ["--device", device] if device is not None else []
        self.args = [sys.executable, *program, mode, *serial, *network, *args]
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen(self.args, env=env, stdout=self._log, stderr=self._log)
        self._notify = notify
        try:
            while True:
                message = self.notification(READY_TIMEOUT_S)
                if message is None:
                    raise TimeoutError(f"gateway not ready: {self.log()}")
                if "READY=1" in message:
                    break
        finally:
            if not keep_notify:
                self._close_notify()

    def notification(self, timeout: float) -> str | None:
        """The next message the gateway sent to systemd, or None after timeout seconds.
        Unread messages are kept, at most 10 (net.unix.max_dgram_qlen); with the queue
        full, the gateway drops WATCHDOG=1 and STATUS= and waits to send the others."""
        self._notify.settimeout(timeout)
        try:
            return self._notify.recv(4096).decode()
        except socket.timeout:
            return None

    def _close_notify(self) -> None:
        if self._notify is not None:
            self._notify.close()
            self._notify = None

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def stop(self) -> int:
        stop(self.proc)
        self._close_notify()
        self._log.close()
        return self.proc.returncode


class Peer:
    """A Python peer script from tests/peers, ready when it prints READY."""

    def __init__(self, script: str, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-u", str(PEERS / script), *args],
                                     stdout=subprocess.PIPE, text=True)
        _read_lines_until(self.proc, self.proc.stdout, lambda ls: "READY" in ls, READY_TIMEOUT_S)

    def stop(self) -> None:
        stop(self.proc)


@contextlib.contextmanager
def reachable_by_others(path: Path = CHECKOUT):
    """Let other users reach path (and so the venv's python and the checkout's mbgw), for a
    command run as another user: search permission on every ancestor that lacks it (a CI
    clone may live in a 0700 temporary directory), restored afterwards."""
    changed = []
    traverse = stat.S_IXGRP | stat.S_IXOTH     # group too: the user may be in the owner's group
    for directory in [path, *path.parents]:
        mode = directory.stat().st_mode
        if mode & traverse != traverse:
            os.chmod(directory, mode | traverse)
            changed.append((directory, mode))
    try:
        yield
    finally:
        for directory, mode in changed:
            os.chmod(directory, stat.S_IMODE(mode))


def logged_counters(line: str) -> dict[str, int]:
    """The counters of a gateway's "... stopped; counters: name=value ..." log line."""
    words = line.split("stopped; counters:", 1)[1].split()
    return {k: int(v) for k, v in (w.split("=") for w in words)}


def stop_counters(gw: Gateway) -> dict[str, int]:
    """Stop the gateway (it must exit 0) and return the counters of its one 'stopped' log
    line."""
    assert gw.stop() == 0, gw.log_path.read_text()
    text = gw.log_path.read_text()
    lines = [row for row in text.splitlines() if "stopped; counters:" in row]
    assert len(lines) == 1, text
    return logged_counters(lines[0])
