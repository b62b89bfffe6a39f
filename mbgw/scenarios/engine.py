"""A runner's scenarios (the serial line's, or the TCP runner's): their schedule, their runs'
results in the table, their state and counters.  The runner asks `next(now)` for a run, sends
its PDU, and hands the reply (or the error) to `done`; it sleeps at most `due_in(now)` and
also wakes on `wake_fd` (a change scenario's data changed).  Thread-safe: the runner's thread
runs scenarios, the control and status threads read and enable them.

Two kinds of run never reach the runner: a write whose table registers nobody has written
since start waits ("waiting for data", unless send-unwritten), and a run for a device or
server that is down (the runner's `health`, mbgw.scenarios.health) is skipped, "device down",
but for the probe the demotion rule lets through.

A change write is owed until its device has had it: one skipped (its device down) or sent
and never answered (a timeout, the line lost) is pending again as soon as its device is not
down, with the table's data then; demotion spaces the attempts to a device that stays
silent."""
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Protocol

from mbgw.audit import Kind, event
from mbgw.config.scenario import ScenarioConfig
from mbgw.scenarios import exchange
from mbgw.scenarios.plan import Planner

log = logging.getLogger("mbgw.scenarios")

STARTING, RUNNING, ERROR, DISABLED = "starting", "running", "error", "disabled"
STATES = (STARTING, RUNNING, ERROR, DISABLED)

# FC 7's flag is one per table, and a table has up to two runners' Scenarios: the ids of
# those with a scenario in error, by table.
_IN_ERROR: dict[int, set[int]] = {}
_IN_ERROR_LOCK = threading.Lock()


# A run that got no reply: its device may never have had the write.
UNANSWERED = (exchange.TIMEOUT, exchange.EXCEPTION_KINDS[0x0A])

DEFAULT_TEST_WAIT_S = 60.0     # how long `scenario test` waits for its runner


class Health(Protocol):
    """A runner's demotion (mbgw.scenarios.health)."""
    down_kind: str                  # the error kind of a run skipped

    def down(self, sc: ScenarioConfig) -> bool: ...

    def state(self, sc: ScenarioConfig) -> str: ...

    def admit(self, sc: ScenarioConfig, now: float) -> bool: ...

    def next_probe_in(self, sc: ScenarioConfig) -> float | None: ...


@dataclass
class Run:
    scenario: ScenarioConfig
    pdu: bytes
    started: float
    probe: bool = False        # its device (server) is down: this run is the probe


class TestRun(Run):
    """A `scenario test` run: the runner does it like a Run (take_test, test_done), between
    its own runs; the operator's thread waits for `result`."""
    __test__ = False        # not a pytest class

    def __init__(self, scenario: ScenarioConfig, pdu: bytes, started: float) -> None:
        super().__init__(scenario, pdu, started)
        self.finished = threading.Event()
        self.result: dict | None = None


class _State:
    """One scenario's state and counters (fresh when it is added or changed)."""

    def __init__(self, scenario: ScenarioConfig, now: float) -> None:
        self.scenario = scenario
        self.state = STARTING if scenario.enabled else DISABLED
        self.message = ""
        self.retrying = False       # the run in progress is being sent again
        self.runs = 0
        self.successes = 0
        self.errors: dict[str, int] = {}
        self.retries = 0
        self.last_success_wall: float | None = None   # time.time()
        self.error_since: float | None = None          # time.time() it went into error
        self.last_latency_s: float | None = None
        self.data_time: float | None = None            # the clock's time of the last good read
        self.since = now                               # when it started (the age before data)
        self.overruns = 0
        self.watch: int | None = None                  # the table watch of a change scenario
        self.stale = False

    def data_age(self, now: float) -> float | None:
        return None if self.data_time is None else now - self.data_time


def _waiting_message(unwritten: int) -> str:
    return f"{exchange.WAITING}: table register {unwritten} not written since start"


def _message(state: _State) -> str:
    """What the status says: "retrying" while the run in progress is sent again."""
    if not state.retrying:
        return state.message
    return exchange.RETRYING.replace("slave", "server") if state.scenario.kind == "tcp" \
        else exchange.RETRYING


def _same_but_enabled(a: ScenarioConfig, b: ScenarioConfig) -> bool:
    return replace(a, enabled=True) == replace(b, enabled=True)


class Scenarios:
    """The scenarios of one kind ("serial" or "tcp") of `configs`, run on one runner."""

    def __init__(self, configs: Iterable[ScenarioConfig], table, kind: str,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.kind = kind
        self.table = table
        self.clock = clock
        self.wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._lock = threading.RLock()
        self._states: dict[str, _State] = {}
        now = clock()
        self._planner = Planner((), now)
        self._flag = False                  # FC 7's "a scenario is in error", as last set
        self._tests: deque[TestRun] = deque()
        self.health: Health | None = None    # the runner's demotion; None: every run is sent
        self._owed: set[str] = set()     # change scenarios skipped or unanswered
        self.reconfigure(configs)

    # --- the runner's side ---

    def due_in(self, now: float) -> float | None:
        """Seconds until the next run is due, 0 if one is, None if none is planned; also
        takes the table's changes and updates what is stale."""
        with self._lock:
            self._take_changes()
            self.tick(now)
            if self._tests:
                return 0.0
            due = self._planner.due_in(now)
            stale_due = self._next_stale_check(now)
            if stale_due is not None and (due is None or stale_due < due):
                return stale_due
            return due

    def next(self, now: float, can_run: Callable[[ScenarioConfig], bool] | None = None
             ) -> Run | None:
        """The run to do now, its PDU built from the table now; None if none is due.  Those
        due that must not be sent (waiting for data, their device down and no probe due) are
        booked and passed over.  can_run: see Planner.take."""
        with self._lock:
            self._take_changes()
            while (scenario := self._planner.take(now, can_run)) is not None:
                state = self._states[scenario.name]
                state.overruns += self._planner.last_missed
                unwritten = self._unwritten(scenario)
                if unwritten is not None:
                    self._planner.finished(scenario.name, now)
                    self._wait_for_data(state, unwritten)
                    continue
                health = self.health
                probe = health is not None and health.down(scenario)
                if probe and health is not None and not health.admit(scenario, now):
                    self._planner.finished(scenario.name, now)
                    if scenario.on_change:
                        self._owed.add(scenario.name)
                    self._record(state, exchange.Result(health.down_kind), 0, 0.0, now)
                    continue
                return Run(scenario, exchange.request_pdu(scenario, self.table), now, probe)
            return None

    def done(self, run: Run, reply_pdu: bytes | None, error_kind: str | None,
             retries: int = 0) -> exchange.Result:
        """A run ended: the reply (None for a broadcast, or after error_kind: timeout,
        connection-lost, ...) checked and its data stored; state and counters updated."""
        now = self.clock()
        with self._lock:
            sc = run.scenario
            if error_kind is not None:
                result = exchange.Result(error_kind)
            elif reply_pdu is None:
                result = exchange.OK if sc.broadcast else exchange.Result(exchange.TIMEOUT)
            else:
                result = exchange.apply_reply(sc, self.table, reply_pdu, run.pdu)
            self._planner.finished(sc.name, now)
            state = self._states.get(sc.name)
            if state is None or state.scenario != sc:
                return result          # removed or changed while it ran: counts nothing
            if sc.on_change and reply_pdu is None and result.kind in UNANSWERED:
                self._owed.add(sc.name)
            self._record(state, result, retries, now - run.started, now,
                         still_down=run.probe and self.health is not None
                         and self.health.down(sc))
            return result

    def tick(self, now: float) -> None:
        """Mark stale the read ranges whose data is older than their stale-after, current
        again the others."""
        with self._lock:
            for state in self._states.values():
                sc = state.scenario
                if sc.stale_after_ms and state.state != DISABLED:
                    since = state.data_time if state.data_time is not None else state.since
                    self._set_stale(state, now - since >= sc.stale_after_ms / 1000)

    # --- the operator's side ---

    def enable(self, name: str, on: bool) -> bool:
        """Enable or disable a scenario until the next reload; False when there is none of
        that name."""
        with self._lock:
            state = self._states.get(name)
            if state is None:
                return False
            if on == (state.state != DISABLED):
                return True
            now = self.clock()
            if on:
                state.state, state.message, state.since = STARTING, "", now
                state.retrying = False
                self._planner.add(state.scenario, now)
                os.eventfd_write(self.wake_fd, 1)     # a runner at rest looks again
            else:
                state.state, state.message = DISABLED, ""   # out of error, not "running again"
                state.error_since = None
                state.retrying = False
                self._update_flag()
                self._planner.remove(name)
                self._set_stale(state, False)
            log.info("scenario %s %s", name, "enabled" if on else "disabled")
            return True

    def reconfigure(self, configs: Iterable[ScenarioConfig]) -> None:
        """Take a new list (this runner's kind of it): unchanged scenarios keep their
        counters and schedule, changed ones restart at "starting" with fresh counters."""
        wanted = {sc.name: sc for sc in configs if sc.kind == self.kind}
        now = self.clock()
        with self._lock:
            for name in [n for n in self._states if n not in wanted]:
                self._drop(self._states.pop(name))
            for name, sc in wanted.items():
                old = self._states.get(name)
                if old is not None and _same_but_enabled(old.scenario, sc):
                    old.scenario = sc
                    self._planner.replace(sc)
                    self.enable(name, sc.enabled)
                    continue
                if old is not None:
                    self._drop(old)
                self._states[name] = state = _State(sc, now)
                self._watch(state)
                if sc.enabled:
                    self._planner.add(sc, now)
            self._states = {name: self._states[name] for name in wanted}
            self._update_flag()

    def names(self) -> list[str]:
        with self._lock:
            return list(self._states)

    def get(self, name: str) -> ScenarioConfig | None:
        with self._lock:
            state = self._states.get(name)
            return None if state is None else state.scenario

    def data_ages(self) -> dict[str, float | None]:
        """Seconds since each scenario last read its data (None: not yet), taken under one
        hold of the lock."""
        now = self.clock()
        with self._lock:
            return {name: state.data_age(now) for name, state in self._states.items()}

    def status(self) -> list[dict]:
        """Each scenario's state and counters, in the configuration's order."""
        now = self.clock()
        with self._lock:
            return [self._status(state, now) for state in self._states.values()]

    def request_test(self, sc: ScenarioConfig, wait_s: float = DEFAULT_TEST_WAIT_S,
                     pdu: bytes | None = None) -> dict:
        """From any thread but the runner's: have the runner run `sc` once (take_test,
        test_done) and wait for its result (test_result's dict).  pdu: the request to send to
        sc's device instead of sc's own (a write from MQTT)."""
        with self._lock:
            unwritten = None if pdu is not None else self._unwritten(sc)
            if unwritten is not None:
                return {"error": f"{_waiting_message(unwritten)}: nothing sent "
                                 f"(send-unwritten=true sends it all the same)"}
            test = TestRun(sc, pdu or exchange.request_pdu(sc, self.table), 0.0)
            self._tests.append(test)
        os.eventfd_write(self.wake_fd, 1)
        if not test.finished.wait(wait_s):
            with self._lock:
                if test in self._tests:
                    self._tests.remove(test)
            return {"error": f"the {self.kind} scenarios' runner did not run the test within "
                             f"{wait_s:g} s"}
        assert test.result is not None
        return test.result

    def take_test(self, now: float) -> TestRun | None:
        """The runner's side of request_test: a test to run now, or None."""
        with self._lock:
            if not self._tests:
                return None
            test = self._tests.popleft()
            test.started = now
            return test

    def test_done(self, test: TestRun, reply_pdu: bytes | None, error_kind: str | None,
                  retries: int = 0) -> None:
        test.result = self.test_result(test.scenario, test.pdu, reply_pdu, error_kind, retries,
                                       self.clock() - test.started)
        test.finished.set()

    def test(self, sc: ScenarioConfig, run_fn: Callable[[bytes], tuple]) -> dict:
        """Run `sc` once (it need not be configured): run_fn(pdu) -> (reply_pdu | None,
        error_kind | None, retries), called by the runner between its own runs.  A read's
        data is returned, not stored; nothing is counted."""
        with self._lock:
            pdu = exchange.request_pdu(sc, self.table)
        started = self.clock()
        reply, error_kind, retries = run_fn(pdu)
        return self.test_result(sc, pdu, reply, error_kind, retries, self.clock() - started)

    def retrying(self, sc: ScenarioConfig) -> None:
        """A run of sc got no answer and is sent again: its message says so until the run
        ends (VPGate's "Slave not responding, retrying...")."""
        with self._lock:
            state = self._states.get(sc.name)
            if state is not None and state.scenario is sc and state.state != DISABLED:
                state.retrying = True

    def test_result(self, sc: ScenarioConfig, pdu: bytes, reply: bytes | None,
                    error_kind: str | None, retries: int, latency_s: float) -> dict:
        """What `mbgw scenario test` prints, from a run the runner did."""
        if error_kind is not None:
            result = exchange.Result(error_kind)
        elif reply is None:
            result = exchange.OK if sc.broadcast else exchange.Result(exchange.TIMEOUT)
        else:
            result = exchange.check_reply(sc, pdu, bytes(reply))
        return {"scenario": sc.fields(), "ok": result.ok, "kind": result.kind,
                "message": result.message(sc.kind == "tcp"), "data": result.data,
                "request": pdu.hex(" "), "reply": None if reply is None else bytes(reply).hex(" "),
                "retries": retries, "latency_ms": round(latency_s * 1000, 3)}

    def close(self) -> None:
        with self._lock:
            for state in self._states.values():
                self._drop(state)
            self._states.clear()
            self._update_flag()
        os.close(self.wake_fd)

    # --- inside, the lock held ---

    def _record(self, state: _State, result: exchange.Result, retries: int,
                latency: float, now: float, still_down: bool = False) -> None:
        """still_down: the run was its device's probe, which failed: its message stays
        "device down" (the probe's own error is counted)."""
        state.runs += 1
        state.retries += retries
        state.retrying = False
        if result.ok:
            state.successes += 1
            state.last_success_wall = time.time()
            state.last_latency_s = latency
            if state.scenario.reads:
                state.data_time = now
                self._set_stale(state, False)
            if state.state != DISABLED:
                self._leave_error(state)
                state.state, state.message = RUNNING, ""
            return
        state.errors[result.kind or ""] = state.errors.get(result.kind or "", 0) + 1
        if state.state == DISABLED:
            return
        tcp = state.scenario.kind == "tcp"
        message = result.message(tcp)
        if still_down and self.health is not None:
            message = exchange.error_message(self.health.down_kind, tcp)
        if state.state != ERROR:
            state.error_since = time.time()
        if state.state != ERROR or state.message != message:
            event(log, Kind.SCENARIO_ERROR, "scenario %s (%s): %s", state.scenario.name,
                  state.scenario.target, message, scenario=state.scenario.name,
                  reason=message)
        state.state, state.message = ERROR, message
        self._update_flag()

    def _leave_error(self, state: _State) -> None:
        if state.state == ERROR:
            log.info("scenario %s (%s): running again", state.scenario.name,
                     state.scenario.target)
            state.state, state.error_since = RUNNING, None
            self._update_flag()

    def _update_flag(self) -> None:
        """FC 7's bit 1: some scenario of this runner is in error (set on a change only)."""
        flag = any(s.state == ERROR for s in self._states.values())
        if flag == self._flag:
            return
        self._flag = flag
        with _IN_ERROR_LOCK:
            engines = _IN_ERROR.setdefault(id(self.table), set())
            (engines.add if flag else engines.discard)(id(self))
            self.table.set_flags(scenario_error=bool(engines))

    def _set_stale(self, state: _State, on: bool) -> None:
        if state.stale == on:
            return
        state.stale = on
        read = state.scenario.read_range()
        if read is not None:
            self.table.set_stale(read[0], read[1], on)
        if on:
            log.warning("scenario %s: data older than %d ms: reads of table %d+%d answer 0x0B",
                        state.scenario.name, state.scenario.stale_after_ms,
                        *(read or (0, 0)))

    def _next_stale_check(self, now: float) -> float | None:
        soonest = None
        for state in self._states.values():
            sc = state.scenario
            if sc.stale_after_ms and not state.stale and state.state != DISABLED:
                since = state.data_time if state.data_time is not None else state.since
                due = max(0.0, since + sc.stale_after_ms / 1000 - now)
                soonest = due if soonest is None else min(soonest, due)
        return soonest

    def _watch(self, state: _State) -> None:
        sc = state.scenario
        if sc.on_change:
            first, count = sc.write_range() or (0, 0)
            # waiting for data: a first write is data even when it stores the table's value
            state.watch = self.table.watch(first, count, self.wake_fd,
                                           first_writes=not sc.send_unwritten)

    def _unwritten(self, sc: ScenarioConfig) -> int | None:
        """The first table register a write would send that nobody has written since start,
        None when it may be sent (all written, a read, or send-unwritten)."""
        if not sc.writes or sc.send_unwritten:
            return None
        first, count = sc.write_range() or (0, 0)
        return self.table.unwritten(first, count)

    def _wait_for_data(self, state: _State, unwritten: int) -> None:
        """A write not sent: its message says why (logged when it begins to wait); its state
        stays (starting: nothing it sends was written before, so it never ran)."""
        message = _waiting_message(unwritten)
        if not state.message.startswith(exchange.WAITING):
            log.info("scenario %s (%s): %s; it is sent once a client (or a read, or the "
                     "table file) has written it", state.scenario.name, state.scenario.target,
                     message)
        state.message = message

    def _drop(self, state: _State) -> None:
        if state.watch is not None:
            self.table.unwatch(state.watch)
            state.watch = None
        self._set_stale(state, False)
        self._planner.remove(state.scenario.name)

    def _take_changes(self) -> None:
        if self._owed:
            self._repay()
        try:
            os.eventfd_read(self.wake_fd)
        except BlockingIOError:
            return
        for state in self._states.values():
            if state.watch is not None:
                count = (state.scenario.write_range() or (0, 1))[1]
                if self.table.take_change(state.watch, count) is not None \
                        and state.state != DISABLED:
                    self._planner.changed(state.scenario.name)

    def _repay(self) -> None:
        """A change scenario skipped while its device was down, or not answered, is pending
        again once the device is not down (its data as it is then)."""
        for name in list(self._owed):
            state = self._states.get(name)
            if state is None or state.state == DISABLED:
                self._owed.discard(name)
            elif self.health is None or not self.health.down(state.scenario):
                self._owed.discard(name)
                self._planner.changed(name)

    def _status(self, state: _State, now: float) -> dict:
        sc = state.scenario
        age = state.data_age(now)
        return {
            "name": sc.name, "kind": sc.kind, "target": sc.target, "function": sc.function,
            "trigger": "change" if sc.on_change else f"{sc.cycle_ms} ms",
            "state": state.state, "message": _message(state), "runs": state.runs,
            "successes": state.successes, "errors": dict(state.errors),
            "retries": state.retries, "overruns": state.overruns,
            "last_success": state.last_success_wall,
            "error_since": state.error_since,
            "last_latency_ms": None if state.last_latency_s is None
            else round(state.last_latency_s * 1000, 3),
            "data_age_s": None if age is None else round(age, 3),
            "stale": state.stale,
            "next_probe_in_s": self._next_probe_in(state),
        }

    def _next_probe_in(self, state: _State) -> float | None:
        """While its runs are skipped (its device down): seconds until one may go as the
        probe."""
        health = self.health
        if health is None or state.state != ERROR or \
                state.message != exchange.error_message(health.down_kind,
                                                        state.scenario.kind == "tcp"):
            return None
        wait = health.next_probe_in(state.scenario)
        return None if wait is None else round(wait, 3)
