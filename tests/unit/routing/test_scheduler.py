"""The line queue (mbgw.routing.queue.Scheduler): fair between clients, in order within a
client, and an eventfd through which other threads wake the line thread.

The rule (docs/architecture.md, slave path step 4): one turn per waiting client, taken in the
order the turns began: a client with nothing queued begins one when its request arrives
(Job.received_ns); a client with more requests after the one taken begins its next when the
line comes to take a job again.  Times here are made up, as the kernel's receive timestamps
would give them; a job without one arrived at 0."""
import os
import time

import pytest

from mbgw.routing.queue import SCENARIO_TURN, Job, Queue, Scheduler


@pytest.fixture
def scheduler():
    s = Scheduler()
    yield s
    s.close()


def _job(client: str, n: int, arrived_ns: int = 0) -> Job:
    return Job(client, n, 1, bytes((1, 3, 0, n, 0, 1)), arrived_ns)


def _submit(scheduler: Scheduler, queue: Queue, client: str, count: int) -> None:
    for n in range(count):
        scheduler.submit(queue, _job(client, n))


def _drain(scheduler: Scheduler) -> list[tuple[str, int]]:
    taken = []
    while (job := scheduler.take()) is not None:
        taken.append(("scenario", 0) if job is SCENARIO_TURN else (job.client, job.tid))
    return taken


def _woken(scheduler: Scheduler) -> bool:
    try:
        os.eventfd_read(scheduler.wake_fd)
    except BlockingIOError:
        return False
    return True


def test_take_on_an_empty_scheduler_returns_none(scheduler):
    assert scheduler.take() is None
    assert scheduler.take() is None


def test_one_client_is_served_in_order(scheduler):
    queue = Queue()
    _submit(scheduler, queue, "a", 5)
    assert _drain(scheduler) == [("a", n) for n in range(5)]


def test_clients_take_turns(scheduler):
    a, b, c = Queue(), Queue(), Queue()
    _submit(scheduler, a, "a", 3)
    _submit(scheduler, b, "b", 2)
    _submit(scheduler, c, "c", 1)
    assert _drain(scheduler) == [("a", 0), ("b", 0), ("c", 0),
                                 ("a", 1), ("b", 1),
                                 ("a", 2)]


def test_a_pipelining_client_does_not_starve_a_latecomer(scheduler):
    busy, late = Queue(), Queue()
    _submit(scheduler, busy, "busy", 16)
    assert scheduler.take().client == "busy"
    scheduler.submit(late, _job("late", 0, time.monotonic_ns()))   # during busy's transaction
    assert [scheduler.take().client for _ in range(3)] == ["late", "busy", "busy"]


def test_a_request_read_late_goes_before_the_turns_that_began_after_it_arrived(scheduler):
    """Requests read in one poll after a transaction come in fd order; the ring takes them
    in the order they arrived."""
    a, b, c, d = Queue(), Queue(), Queue(), Queue()
    scheduler.submit(a, _job("a", 0, 100))
    scheduler.submit(b, _job("b", 0, 400))
    scheduler.submit(c, _job("c", 0, 200))
    scheduler.submit(d, _job("d", 0, 300))
    assert _drain(scheduler) == [("a", 0), ("c", 0), ("d", 0), ("b", 0)]


def test_turns_that_began_at_the_same_time_keep_the_order_they_were_read_in(scheduler):
    a, b = Queue(), Queue()
    scheduler.submit(a, _job("a", 0, 100))
    scheduler.submit(b, _job("b", 0, 100))
    assert _drain(scheduler) == [("a", 0), ("b", 0)]


def test_a_client_with_more_requests_lines_up_again_when_the_line_is_free(scheduler):
    """Behind what arrived during its transaction (read after it, dated before the line
    came back), ahead of what arrives after."""
    busy, during, after = Queue(), Queue(), Queue()
    _submit(scheduler, busy, "busy", 3)
    assert scheduler.take().tid == 0
    scheduler.submit(during, _job("during", 0, time.monotonic_ns()))
    assert scheduler.take().client == "during"
    # busy lined up again as "during" was taken: what arrives now comes behind it
    scheduler.submit(after, _job("after", 0, time.monotonic_ns()))
    assert _drain(scheduler) == [("busy", 1), ("after", 0), ("busy", 2)]


def test_each_waiting_client_is_served_once_before_anyone_twice(scheduler):
    """However deep the queues and however the requests were read, a request at the head of
    its queue waits for at most one transaction of each other client."""
    queues = {name: Queue() for name in "abcd"}
    for n in range(4):
        for name, queue in queues.items():
            scheduler.submit(queue, _job(name, n, 10 * n + ord(name)))
    taken = _drain(scheduler)
    assert [name for name, _ in taken] == list("abcd") * 4
    assert [n for _, n in taken] == [n for n in range(4) for _ in range(4)]


def test_a_client_that_runs_dry_rejoins_at_the_back(scheduler):
    a, b = Queue(), Queue()
    _submit(scheduler, a, "a", 1)
    _submit(scheduler, b, "b", 2)
    assert scheduler.take().client == "a"
    scheduler.submit(a, _job("a", 1))
    assert _drain(scheduler) == [("b", 0), ("a", 1), ("b", 1)]


def test_discard_forgets_a_clients_pending_jobs(scheduler):
    a, b = Queue(), Queue()
    _submit(scheduler, a, "a", 3)
    _submit(scheduler, b, "b", 2)
    scheduler.discard(a)
    assert _drain(scheduler) == [("b", 0), ("b", 1)]


def test_discard_of_an_idle_client_is_harmless(scheduler):
    a, b = Queue(), Queue()
    scheduler.discard(a)
    _submit(scheduler, b, "b", 1)
    scheduler.discard(a)
    assert _drain(scheduler) == [("b", 0)]


def test_discard_of_the_client_whose_job_is_on_the_line_forgets_the_rest(scheduler):
    a, b = Queue(), Queue()
    _submit(scheduler, a, "a", 3)
    assert scheduler.take().client == "a"
    _submit(scheduler, b, "b", 1)
    scheduler.discard(a)
    assert scheduler.depth == 1
    assert _drain(scheduler) == [("b", 0)]
    scheduler.submit(a, _job("a", 9))
    assert _drain(scheduler) == [("a", 9)]


def test_a_discarded_client_can_queue_again(scheduler):
    a = Queue()
    _submit(scheduler, a, "a", 2)
    scheduler.discard(a)
    scheduler.submit(a, _job("a", 9))
    assert _drain(scheduler) == [("a", 9)]


def test_submit_and_take_never_signal_the_eventfd(scheduler):
    """Only the line thread submits and takes: the eventfd is for other threads."""
    assert scheduler.take() is None
    _submit(scheduler, Queue(), "a", 3)
    assert scheduler.take() is not None
    assert not _woken(scheduler)


def test_wake_always_signals(scheduler):
    scheduler.wake()
    assert _woken(scheduler)
    assert not _woken(scheduler)


# --- the scenario queue: one more participant of the ring (issue 15) ---

def test_the_scenario_queue_takes_its_turn_among_the_clients(scheduler):
    a, b = Queue(), Queue()
    scheduler.submit(a, _job("a", 0, 100))
    scheduler.scenario_due(200)
    scheduler.submit(b, _job("b", 0, 300))
    assert _drain(scheduler) == [("a", 0), ("scenario", 0), ("b", 0)]


def test_a_due_scenario_queue_has_one_turn_however_often_it_is_told(scheduler):
    scheduler.scenario_due(100)
    scheduler.scenario_due(200)
    assert _drain(scheduler) == [("scenario", 0)]
    assert scheduler.depth == 0


def test_scenarios_always_due_and_busy_clients_alternate(scheduler):
    """The line thread tells the scheduler a scenario is due before each take: neither the
    scenario list nor a pipelining client starves the other."""
    busy = Queue()
    _submit(scheduler, busy, "busy", 3)
    taken = []
    for _ in range(6):
        scheduler.scenario_due(time.monotonic_ns())
        job = scheduler.take()
        taken.append("scenario" if job is SCENARIO_TURN else job.client)
    assert taken == ["busy", "scenario", "busy", "scenario", "busy", "scenario"]


def test_each_client_is_served_once_between_two_scenario_runs(scheduler):
    queues = {name: Queue() for name in "abc"}
    for n in range(2):
        for name, queue in queues.items():
            scheduler.submit(queue, _job(name, n, 10 * n + ord(name)))
    scheduler.scenario_due(0)
    taken = [scheduler.take()]
    for _ in range(7):
        scheduler.scenario_due(time.monotonic_ns())
        taken.append(scheduler.take())
    names = ["s" if job is SCENARIO_TURN else job.client for job in taken]
    assert names == ["s", "a", "b", "c", "s", "a", "b", "c"]


def test_a_held_address_gives_way_and_keeps_its_turn(scheduler):
    """A request to an address in its late window is passed over: the next turn whose request
    may go is taken, and the held one, still first in the ring, goes once it is free; a
    client's own later requests never overtake its held one (order within a client), and a
    scenario's turn is never held here (its address is the run's, known later)."""
    a, b, c = Queue(), Queue(), Queue()
    scheduler.submit(a, Job("a", 1, 17, bytes((17, 3, 0, 0, 0, 2)), 10))
    scheduler.submit(a, Job("a", 2, 1, bytes((1, 3, 0, 0, 0, 2)), 11))
    scheduler.submit(b, Job("b", 1, 17, bytes((17, 3, 0, 50, 0, 2)), 20))
    scheduler.submit(c, Job("c", 1, 1, bytes((1, 3, 0, 0, 0, 1)), 30))
    scheduler.scenario_due(40)
    held = {17}
    taken = scheduler.take(held.__contains__)
    assert (taken.client, taken.tid) == ("c", 1)
    assert scheduler.take(held.__contains__) is SCENARIO_TURN
    assert scheduler.take(held.__contains__) is None
    assert scheduler.depth == 3
    held.clear()
    assert _drain(scheduler) == [("a", 1), ("b", 1), ("a", 2)]
    assert scheduler.depth == 0
