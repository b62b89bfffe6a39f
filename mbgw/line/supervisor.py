"""The skeleton of both modes' line threads (LineThread), and when a lost serial device is
opened again (Reopening).

The line thread looks at the device's path every LOOK_S (a stat, links followed: a link to a
vanished pty is absent).  An absent path is only looked at: no open attempt, no log line.  A
file that appears at the path is opened at once.  The file that has just failed, or that
fails to open, is held back: it is tried again after a pause that doubles from
BACKOFF_FIRST_S to BACKOFF_MAX_S, and its first failed open is logged once.

A device that is not there when the gateway starts (a USB adapter not plugged in yet, its
/dev/serial/by-id link not made yet) is waited for the same way (open_at_start): the gateway
starts, listens and refuses what needs the line, and opens the device when it appears.
"""
import errno
import logging
import os
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Generic, Protocol, TypeVar

from mbgw.errors import SerialError
from mbgw.line import native
from mbgw.line.raw import RawMonitor
from mbgw.line.serial_line import SerialLine

if TYPE_CHECKING:      # the settings' type only: the line never reads the configuration files
    from mbgw.config.model import SerialConfig

log = logging.getLogger("mbgw.line")

LOOK_S = 0.1
BACKOFF_FIRST_S = 0.5
BACKOFF_MAX_S = 5.0
# What the watchdog (mbgw.ops.service.tell_systemd) allows a turn of a line thread's loop on
# top of what the line's settings say it may take: the thread's own time, scheduling delays.
TURN_MARGIN_S = 1.0


def longest_frame_s(serial: "SerialConfig") -> float:
    """The time the longest frame of the line's protocol takes on the wire."""
    chars = native.ASCII_MAX_FRAME if serial.protocol == "ascii" else native.RTU_MAX_ADU
    return chars * serial.char_ns / 1e9


def open_at_start(serial: "SerialConfig", counters=None) -> SerialLine | None:
    """The line, opened; None when the device is not there (nothing at its path, or a link
    to nothing): the line thread opens it when it appears.  Raises SerialError when it is
    there and does not open (in use, not a tty, no permission)."""
    try:
        return SerialLine(serial, counters)
    except SerialError:
        if _file_at(serial.device) is None:
            return None
        raise


def _file_at(path: str) -> tuple[int, int] | None:
    """The file the path leads to now (links followed), or None."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


class Reopening:
    """One device being reopened, from its loss (or new settings) until it opens."""

    def __init__(self, device: str, pause: bool) -> None:
        """pause: the device has just failed, so the file now at its path waits first."""
        self._device = device
        self._held: tuple[int, int] | None = None     # the file backed off
        self._open_at = 0.0
        self._backoff_s = BACKOFF_FIRST_S
        self._warned = False
        self.absent = False         # nothing was at the path at the last look
        if pause:
            self._hold(_file_at(device))

    def attempt(self, open_device):
        """Call open_device() (it raises SerialError) if the device is there and not held
        back; returns what it returned, or None."""
        found = _file_at(self._device)
        self.absent = found is None
        if found is None:
            self._held = None
            return None
        if found == self._held and time.monotonic() < self._open_at:
            return None
        try:
            return open_device()
        except SerialError as err:
            self._failed(found, err)
            return None

    def _failed(self, found: tuple[int, int], err: SerialError) -> None:
        if err.errno == errno.ENOENT:       # gone since the look: absent, nothing to hold
            self._held = None
            return
        self._hold(found)
        if not self._warned:
            self._warned = True
            log.warning("%s; trying again with backoff up to %g s", err.strerror,
                        BACKOFF_MAX_S)

    def _hold(self, found: tuple[int, int] | None) -> None:
        if found != self._held:
            self._held, self._backoff_s, self._warned = found, BACKOFF_FIRST_S, False
        self._open_at = time.monotonic() + self._backoff_s
        self._backoff_s = min(self._backoff_s * 2, BACKOFF_MAX_S)


class _Settings(Protocol):
    @property
    def serial(self) -> "SerialConfig": ...


Settings = TypeVar("Settings", bound=_Settings)


class RawHub(Protocol):
    """What a line thread needs of the trace hub (mbgw.ops.trace.TraceHub) for its raw view."""
    @property
    def raw_active(self) -> bool: ...

    def add_raw_watcher(self, watcher: Callable[[bool], None]) -> None: ...

    def remove_raw_watcher(self, watcher: Callable[[bool], None]) -> None: ...

    def emit_threadsafe(self, event: dict) -> None: ...


PRIMARY_THREAD = "mbgw-line"


def thread_name(line: str) -> str:
    """The name `ps -L` shows for line's thread: mbgw-line for line serial (as before there
    were other lines), mbgw-NAME for the others, cut to the kernel's 15 characters."""
    return PRIMARY_THREAD if line == "serial" else f"mbgw-{line}"[:15]


class LineThread(threading.Thread, Generic[Settings]):
    """What a line thread is in either mode: it serves one turn at a time (`_turn`) while the
    device is open; when the device is lost it closes it and opens it again when it is back
    (`_while_down` meanwhile); new settings, handed over by reconfigure() from another
    thread, are taken between two turns; stop() is a flag and a wake-up; a bug costs one
    turn, never the thread.  A mode fills in the hooks below."""

    def __init__(self, cfg: Settings, line: SerialLine | None) -> None:
        """line: the device opened, or None when it is not there yet (open_at_start)."""
        super().__init__(name=PRIMARY_THREAD, daemon=True)
        self._cfg = cfg
        self._stopping = False
        self._new_cfg: Settings | None = None
        self._reopening: Reopening | None = None     # while the device is down
        self._line: SerialLine | None = line
        self._opened = line is not None     # the device has been open (its return is "back")
        self._state_since = time.time()     # when the line last opened or was lost
        if line is None:
            self._reopening = Reopening(cfg.serial.device, pause=False)
            self._reopening.absent = True
            log.warning("serial device %s is not there: waiting for it", cfg.serial.device)
        # For systemd's watchdog: the monotonic time the loop last turned, and the longest
        # the thread may wait while nothing happens (-1: no limit; set before start()).
        self.heartbeat = time.monotonic()
        self.idle_ms = -1
        self.line_name = "serial"       # the line's name in the trace (set before start())
        self._raw_hub: RawHub | None = None     # whose raw subscribers watch the line
        self._raw_monitor: RawMonitor | None = None     # since somebody first watched it
        self._answers = False                   # mbgw is the line's slave (master mode)

    def name_line(self, name: str) -> None:
        """The line's name, in the trace and in the thread's name (before start())."""
        self.line_name = name
        self.name = thread_name(name)

    @property
    def up(self) -> bool:
        """The serial device is open (read by the asyncio thread)."""
        return self._line is not None

    @property
    def state(self) -> str:
        """"up", "down" (lost, or there and not opening) or "waiting" (nothing at the
        device's path: waiting for it to appear), for the status."""
        if self._line is not None:
            return "up"
        reopening = self._reopening
        return "waiting" if reopening is not None and reopening.absent else "down"

    @property
    def state_since(self) -> float:
        """When the state last changed between up and down (a Unix time, for the status)."""
        return self._state_since

    def stop(self) -> None:
        self._stopping = True
        self._wake()

    def reconfigure(self, cfg: Settings) -> None:
        """Use cfg from the next turn on (called from another thread)."""
        self._new_cfg = cfg
        self._wake()

    @property
    def turn_limit_s(self) -> float:
        """The longest one turn of the loop takes while all is well (for the watchdog)."""
        raise NotImplementedError

    def run(self) -> None:
        native.line_thread_init()
        native.name_thread(self.name)
        try:
            while not self._stopping:
                self.heartbeat = time.monotonic()
                if self._new_cfg is not None:
                    self._take_new_cfg()
                if self._line is None:
                    self._reopen()
                    continue
                try:
                    hub, raw = self._raw_hub, self._raw_monitor
                    if hub is not None and (hub.raw_active or
                                            (raw is not None and raw.watching)):
                        self._watched_turn(hub)
                    else:
                        self._turn()
                except SerialError as err:
                    self._lost(err)
                except Exception:   # a bug must cost one turn, never the line
                    log.exception("internal error")
        finally:
            self._finish()
            if self._raw_hub is not None:
                self._raw_hub.remove_raw_watcher(self._raw_watcher)

    def _raw_watcher(self, on: bool) -> None:
        self._wake()        # the next turn looks

    def watch_raw(self, hub: "RawHub", answers: bool = False) -> None:
        """Let hub's raw subscribers (`mbgw trace --raw`) watch this line (before start());
        answers: mbgw is the slave on the line (master mode), not its master."""
        self._raw_hub = hub
        self._answers = answers
        hub.add_raw_watcher(self._raw_watcher)

    def _watched_turn(self, hub: "RawHub") -> None:
        """A turn while somebody watches the raw line (or did until now): the C capture set
        for it, its bytes handed to the hub as bursts after it."""
        raw = self._raw_monitor
        if raw is None:
            raw = self._raw_monitor = RawMonitor(0, 0, 0)
        watch = hub.raw_active
        if watch and not raw.watching and self._line is not None:
            s = self._line.cfg
            raw.configure(s.char_ns, s.t35_us, s.stout_ms, s.protocol == "ascii",
                          self._answers)
        raw.watch(watch)
        try:
            self._turn()
        finally:
            for event in raw.take():
                event["line"] = self.line_name
                hub.emit_threadsafe(event)

    def close_line(self) -> None:
        if self._line is not None:
            self._line.close()
            self._line = None
            self._state_since = time.time()
            self._detach()

    def _take_new_cfg(self) -> None:
        cfg, self._new_cfg = self._new_cfg, None
        assert cfg is not None
        old, self._cfg = self._cfg, cfg
        reopen = self._reopens(old.serial, cfg.serial)
        self._configure(old, reopen)
        if reopen:
            self._reopening = Reopening(cfg.serial.device, pause=False)   # tried at once
            if self._line is not None:
                self.close_line()
                log.info("serial line settings changed: reopening %s", cfg.serial.device)

    def _lost(self, err: SerialError) -> None:
        log.error("serial device %s lost: %s; reopening", self._cfg.serial.device, err.strerror)
        self.close_line()
        self._reopening = Reopening(self._cfg.serial.device, pause=True)

    def _reopen(self) -> None:
        """Until the device opens again, the gateway stops, or new settings come."""
        while not self._stopping and self._new_cfg is None:
            self.heartbeat = time.monotonic()
            assert self._reopening is not None
            line = self._reopening.attempt(self._open_line)
            if line is None:
                self._while_down(LOOK_S)
                continue
            self._reopening = None
            self._line = line
            self._state_since = time.time()
            self._attach(line)
            log.info("serial device %s is %s", self._cfg.serial.device,
                     "back" if self._opened else "there: opened")
            self._opened = True
            return

    # --- what a mode fills in ---

    def _wake(self) -> None:
        """Wake the thread from any wait (called from another thread)."""
        raise NotImplementedError

    def _turn(self) -> None:
        """Serve what comes next: one transaction, or a wait for one."""
        raise NotImplementedError

    def _while_down(self, timeout_s: float) -> None:
        """Wait up to timeout_s for a wake-up while the device is down."""
        raise NotImplementedError

    def _open_line(self) -> SerialLine:
        return SerialLine(self._cfg.serial)

    def _attach(self, line: SerialLine) -> None:
        """The device is open (again): set up what serves on it."""

    def _detach(self) -> None:
        """The device has been closed: forget what was set up on it."""

    def _reopens(self, old: "SerialConfig", new: "SerialConfig") -> bool:
        """New serial settings that need the device opened again."""
        return old != new

    def _configure(self, old: Settings, reopen: bool) -> None:
        """self._cfg is new (old was in force until now); the line is reopened after when
        `reopen`."""

    def _finish(self) -> None:
        """The thread ends: close what the mode owns on this thread."""
        self.close_line()
