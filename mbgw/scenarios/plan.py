"""Which scenario runs next, by VPGate's rules (§3.5, §3.6.3): cyclic scenarios one after the
other, each at its period; a change scenario whose data changed right after the cyclic one in
progress; pending change scenarios queued; with several cyclic ones pending, one change
scenario between each.  Pure: the caller gives the time (seconds, monotonic)."""
from collections import deque
from collections.abc import Callable, Iterable

from mbgw.config.scenario import ScenarioConfig


class _Cyclic:
    __slots__ = ("scenario", "period", "planned", "order")

    def __init__(self, scenario: ScenarioConfig, planned: float, order: int) -> None:
        self.scenario = scenario
        self.period = (scenario.cycle_ms or 0) / 1000
        self.planned = planned          # when its next run is due
        self.order = order              # the configuration's order breaks ties


class Planner:
    """The schedule of a runner's enabled scenarios.  take() gives the next one due; the runner
    calls finished() when its run ends (a scenario in flight is never taken again before)."""

    def __init__(self, scenarios: Iterable[ScenarioConfig], now: float) -> None:
        self._cyclic: dict[str, _Cyclic] = {}
        self._change: dict[str, ScenarioConfig] = {}
        self._pending: deque[str] = deque()       # change scenarios whose data changed
        self._in_flight: set[str] = set()
        self._last_was_cyclic = False
        self.last_missed = 0          # the periods the last cyclic run taken had missed
        for scenario in scenarios:
            self.add(scenario, now)

    def add(self, scenario: ScenarioConfig, now: float) -> None:
        """Plan a scenario (a new one, or one enabled again): a cyclic one is due now."""
        self.remove(scenario.name)
        if scenario.on_change:
            self._change[scenario.name] = scenario
        else:
            self._cyclic[scenario.name] = _Cyclic(scenario, now, len(self._cyclic))

    def remove(self, name: str) -> None:
        self._cyclic.pop(name, None)
        self._change.pop(name, None)
        if name in self._pending:
            self._pending.remove(name)

    def replace(self, scenario: ScenarioConfig) -> None:
        """The same scenario with a setting that does not touch its schedule changed."""
        if scenario.name in self._cyclic:
            self._cyclic[scenario.name].scenario = scenario
        elif scenario.name in self._change:
            self._change[scenario.name] = scenario

    def __contains__(self, name: str) -> bool:
        return name in self._cyclic or name in self._change

    def changed(self, name: str) -> None:
        """A change scenario's data changed: it is pending (once, however many changes)."""
        if name in self._change and name not in self._pending:
            self._pending.append(name)

    def finished(self, name: str, now: float) -> None:
        self._in_flight.discard(name)

    def due_in(self, now: float) -> float | None:
        """Seconds until a scenario is due (0: one is), None when none is planned."""
        if any(name not in self._in_flight for name in self._pending):
            return 0.0
        soonest = None
        for entry in self._cyclic.values():
            if entry.scenario.name not in self._in_flight and \
                    (soonest is None or entry.planned < soonest):
                soonest = entry.planned
        return None if soonest is None else max(0.0, soonest - now)

    def take(self, now: float,
             can_run: Callable[[ScenarioConfig], bool] | None = None) -> ScenarioConfig | None:
        """The scenario to run now, or None.  can_run: whether one may start now (a TCP
        runner's server busy with another request); one that may not stays pending."""
        cyclic = self._due_cyclic(now, can_run)
        change = self._pending_change(can_run)
        self.last_missed = 0
        if change is not None and (self._last_was_cyclic or cyclic is None):
            self._pending.remove(change)
            self._last_was_cyclic = False
            self._in_flight.add(change)
            return self._change[change]
        if cyclic is None:
            return None
        self._plan_next(cyclic, now)
        self._last_was_cyclic = True
        self._in_flight.add(cyclic.scenario.name)
        return cyclic.scenario

    def _due_cyclic(self, now: float, can_run) -> _Cyclic | None:
        best = None
        for entry in self._cyclic.values():
            if entry.planned > now or entry.scenario.name in self._in_flight:
                continue
            if can_run is not None and not can_run(entry.scenario):
                continue
            if best is None or (entry.planned, entry.order) < (best.planned, best.order):
                best = entry
        return best

    def _pending_change(self, can_run) -> str | None:
        for name in self._pending:
            if name not in self._in_flight and (can_run is None or can_run(self._change[name])):
                return name
        return None

    def _plan_next(self, entry: _Cyclic, now: float) -> None:
        """Plan from the previous plan, not from now (no drift); a run later than a whole
        period has missed that many: overruns, never queued twice."""
        late = now - entry.planned
        missed = int(late // entry.period) if entry.period > 0 else 0
        self.last_missed = missed
        entry.planned += (missed + 1) * entry.period
