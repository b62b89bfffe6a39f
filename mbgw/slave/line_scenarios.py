"""The serial scenarios on a line's thread (an mbgw.scenarios engine), under the rules of the
clients' requests: the scenario queue takes turns with the clients in the scheduler's ring,
each run is a SerialMaster transaction with the scenario's retries, and a device that is down
gets no run but its probe (the same DeviceStats.admit, through SerialHealth).  The line's idle
wait ends when the next scenario is due (due_s) or the engine's eventfd says a change made one
pending (or an operator's `scenario test` waits: it runs in the scenario queue's turn too)."""
import logging
import time
from typing import Callable

from mbgw.config.model import SlaveConfig
from mbgw.errors import LineTimeout, SerialError
from mbgw.ops.device_stats import DeviceHealth
from mbgw.protocol import pdu
from mbgw.routing.queue import Scheduler
from mbgw.scenarios.engine import Scenarios
from mbgw.scenarios.exchange import EXCEPTION_KINDS, FRAME_WITHOUT_REQUEST, TIMEOUT
from mbgw.scenarios.health import SerialHealth
from mbgw.scenarios.report import trace_event
from mbgw.slave.line_cache import LineCache
from mbgw.slave.transaction import SerialMaster

log = logging.getLogger("mbgw.line")

# A scenario's run while the serial device is lost: the engine's error kind for 0x0A.
PATH_UNAVAILABLE = EXCEPTION_KINDS[pdu.GATEWAY_PATH_UNAVAILABLE]

# on_line(master, adu, retries): the reply PDU (None: a broadcast); LineTimeout; SerialError
# once the lost line is closed
OnLine = Callable[[SerialMaster, bytes, int], bytes | None]


class LineScenarios:
    def __init__(self, engine: Scenarios, cfg: SlaveConfig, scheduler: Scheduler,
                 devices: DeviceHealth, cache: LineCache, trace, on_line: OnLine) -> None:
        """Run engine's scenarios of cfg, and those of the settings to come; trace: the line's
        (LineTrace); on_line: the line thread's transaction, outside the gate."""
        self.engine = engine
        engine.health = SerialHealth(devices)    # the demotion of direct requests
        self.active = bool(serial_scenarios(cfg))   # the engine has scenarios to run
        self.due_s: float | None = None    # until the next scenario is due (None: none is)
        self.woken = False                 # its eventfd was ready (a test, with no scenario)
        self._scheduler = scheduler
        self._devices = devices
        self._cache = cache
        self._trace = trace
        self._on_line = on_line
        self._run_started = 0              # the run traced last began (ns)

    def configure(self, old: SlaveConfig, new: SlaveConfig) -> None:
        if new.scenarios != old.scenarios:
            scenarios = serial_scenarios(new)
            self.engine.reconfigure(scenarios)
            self.active = bool(scenarios)
            self.due_s = None

    def ready(self) -> None:
        """The engine's eventfd is ready: looked at in the next turn even with no scenario
        (an operator's test)."""
        self.woken = True

    def due(self) -> None:
        """The scenario queue gets a turn while a scenario (or a test) is due; the engine
        also takes the table's changes and marks stale data here."""
        self.woken = False
        self.due_s = due = self.engine.due_in(time.monotonic())
        if due == 0:
            self._scheduler.scenario_due(time.monotonic_ns())

    def run(self, master: SerialMaster | None) -> None:
        """The scenario queue's turn: a test that waits, else the next run."""
        engine = self.engine
        test = engine.take_test(time.monotonic())
        if test is not None:
            self._traced_run(test.scenario, test.pdu, None)
            done = self._exchange(master, test.scenario, test.pdu)
            engine.test_done(test, *done)
            self._traced_run(test.scenario, test.pdu, done)
            return
        run = engine.next(time.monotonic())
        if run is not None:
            self._traced_run(run.scenario, run.pdu, None)
            done = self._exchange(master, run.scenario, run.pdu,
                                  lambda: engine.retrying(run.scenario))
            result = engine.done(run, *done)
            self._traced_run(run.scenario, run.pdu, done, result.kind)

    def while_down(self) -> None:
        """None runs, but the engine's eventfd is read, changes are taken and data ages
        (stale-after); a test is answered at once."""
        engine = self.engine
        now = time.monotonic()
        engine.due_in(now)
        while (test := engine.take_test(now)) is not None:
            engine.test_done(test, None, PATH_UNAVAILABLE)

    def _traced_run(self, scenario, request: bytes, done: tuple | None,
                    kind: str | None = None) -> None:
        """A scenario's run in the trace: its request (done None), then its reply or none
        (done: _exchange's), marked with the scenario's name."""
        trace = self._trace
        if not trace.active:
            return
        if done is None:
            self._run_started = time.monotonic_ns()
            trace.emit_threadsafe(trace_event("request", scenario, request, ""))
            return
        reply, error, _ = done
        kind = kind or error
        latency_ms = (time.monotonic_ns() - self._run_started) / 1e6
        if reply is None:
            outcome = "broadcast" if scenario.slave == pdu.BROADCAST and kind is None \
                else kind or TIMEOUT
            event = trace_event("no reply", scenario, request[:1], outcome, latency_ms)
        else:
            event = trace_event("reply", scenario, bytes(reply), kind or "ok", latency_ms)
        trace.emit_threadsafe(event)

    def _exchange(self, master: SerialMaster | None, scenario, request: bytes,
                  on_retry=None) -> tuple:
        """One run of scenario (request: its PDU) on the line with its retries, address 0 a
        broadcast: (reply PDU or None, None or the engine's error kind, the retries made).
        A reply that did not answer the request (another function, another size) is
        returned for the engine to name; none at all is a timeout."""
        if master is None:
            return None, PATH_UNAVAILABLE, 0
        device = self._devices.get(scenario.slave)
        retried, foreign = device.retries, _foreign_frames(device)
        master.on_retry = on_retry
        try:
            reply = self._on_line(master, bytes((scenario.slave,)) + request, scenario.retries)
        except LineTimeout as timeout:
            reply = timeout.mismatch
            if reply is None:       # VPGate 8.2: another master's frames came instead
                kind = FRAME_WITHOUT_REQUEST if _foreign_frames(device) > foreign else TIMEOUT
                return None, kind, device.retries - retried
            return reply, None, device.retries - retried
        except SerialError:         # the line is closed already (on_line)
            return None, PATH_UNAVAILABLE, device.retries - retried
        except Exception:   # a bug must cost one run, never the scenario's schedule
            log.exception("internal error running scenario %s", scenario.name)
            return None, TIMEOUT, device.retries - retried
        finally:
            master.on_retry = None
        cache = self._cache
        if cache.caching:
            cache.scenario_filled(bytes((scenario.slave,)) + request, reply)
        return reply, None, device.retries - retried


def _foreign_frames(device) -> int:
    """Whole frames heard while waiting for device's reply that were not replies: another
    address's, or a request's shape (another master's request read as a reply)."""
    return device.wrong_unit + device.invalid_frames


def serial_scenarios(cfg: SlaveConfig) -> tuple:
    """The scenarios a line in slave mode runs."""
    return tuple(s for s in cfg.scenarios if s.kind == "serial")
