"""The planner (mbgw.scenarios.plan) against VPGate's rules (§3.5, §3.6.3), with a virtual
clock: periods without drift, overruns counted and never queued twice, change scenarios
after the cyclic one in progress, queued, and one between each pending cyclic one."""
from mbgw.config.scenario import ScenarioConfig
from mbgw.scenarios.plan import Planner


def cyclic(name, ms):
    return ScenarioConfig(name=name, function=3, address=0, quantity=1, table=0, slave=1,
                          cycle_ms=ms)


def change(name):
    return ScenarioConfig(name=name, function=6, address=0, quantity=1, table=0, slave=1,
                          on_change=True)


def run(planner, now, duration=0.0):
    sc = planner.take(now)
    if sc is not None:
        planner.finished(sc.name, now + duration)
    return sc and sc.name


def test_periods_do_not_drift():
    p = Planner([cyclic("a", 1000)], 0.0)
    starts = []
    now = 0.0
    while now < 10:
        due = p.due_in(now)
        now += due
        starts.append(round(now, 6))
        sc = p.take(now)
        now += 0.3                     # each run takes 0.3 s
        p.finished(sc.name, now)
    assert starts == [float(i) for i in range(len(starts))]


def test_a_late_run_is_an_overrun_not_queued_twice():
    p = Planner([cyclic("a", 1000)], 0.0)
    assert run(p, 0.0) == "a"
    assert p.take(3.5).name == "a"     # due at 1.0: 2.0 and 3.0 were missed
    assert p.last_missed == 2
    p.finished("a", 3.6)
    assert p.take(3.7) is None         # not again at once
    assert p.due_in(3.7) == 4.0 - 3.7  # still on the 1 s grid
    assert run(p, 4.0) == "a" and p.last_missed == 0


def test_in_flight_is_never_taken_again():
    p = Planner([cyclic("a", 100)], 0.0)
    assert p.take(0.0).name == "a"
    assert p.take(0.5) is None and p.due_in(0.5) is None
    p.finished("a", 0.5)
    assert p.take(0.5).name == "a" and p.last_missed == 4


def test_cyclic_ones_one_after_the_other_in_order():
    p = Planner([cyclic("a", 1000), cyclic("b", 1000), cyclic("c", 500)], 0.0)
    assert [run(p, 0.0) for _ in range(4)] == ["a", "b", "c", None]
    assert p.due_in(0.0) == 0.5
    assert [run(p, 1.0) for _ in range(4)] == ["c", "a", "b", None]


def test_change_runs_right_after_the_cyclic_one_in_progress():
    p = Planner([cyclic("a", 1000), cyclic("b", 1000), change("w")], 0.0)
    first = p.take(0.0)
    assert first.name == "a"
    p.changed("w")                     # while a runs
    p.finished("a", 0.1)
    assert [run(p, 0.1) for _ in range(3)] == ["w", "b", None]


def test_change_queued_once_and_in_order():
    p = Planner([change("w1"), change("w2"), change("w3")], 0.0)
    assert p.due_in(0.0) is None and p.take(0.0) is None
    for name in ("w2", "w1", "w2", "w3"):
        p.changed(name)
    assert p.due_in(0.0) == 0.0
    assert [run(p, 0.0) for _ in range(4)] == ["w2", "w1", "w3", None]


def test_one_change_between_each_pending_cyclic():
    p = Planner([cyclic(n, 1000) for n in "abc"] + [change(f"w{i}") for i in range(3)], 0.0)
    for i in range(3):
        p.changed(f"w{i}")
    order = [run(p, 0.0) for _ in range(7)]
    assert order == ["a", "w0", "b", "w1", "c", "w2", None]


def test_changes_one_after_the_other_when_no_cyclic_is_due():
    p = Planner([cyclic("a", 1000), change("w1"), change("w2")], 0.0)
    assert run(p, 0.0) == "a"
    p.changed("w1")
    p.changed("w2")
    assert [run(p, 0.2) for _ in range(3)] == ["w1", "w2", None]


def test_a_change_during_its_own_run_runs_it_again_after():
    p = Planner([change("w")], 0.0)
    p.changed("w")
    assert p.take(0.0).name == "w"
    p.changed("w")
    assert p.take(0.0) is None and p.due_in(0.0) is None
    p.finished("w", 0.1)
    assert run(p, 0.1) == "w"


def test_can_run_skips_a_busy_target():
    p = Planner([cyclic("a", 1000), cyclic("b", 1000)], 0.0)
    assert p.take(0.0, can_run=lambda sc: sc.name != "a").name == "b"
    assert p.take(0.0).name == "a"


def test_remove_and_add_again():
    p = Planner([cyclic("a", 1000), change("w")], 0.0)
    p.changed("w")
    p.remove("w")
    p.remove("a")
    assert p.due_in(0.0) is None and p.take(0.0) is None
    p.add(cyclic("a", 1000), 5.2)
    assert p.due_in(5.2) == 0.0 and run(p, 5.2) == "a" and p.due_in(5.2) == 1.0
