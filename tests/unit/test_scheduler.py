"""The line queue (mbgw.slave.scheduler): fair between clients, in order within a client, and an
eventfd through which other threads wake the line thread."""
import os

import pytest

from mbgw.slave.scheduler import Job, Queue, Scheduler


@pytest.fixture
def scheduler():
    s = Scheduler()
    yield s
    s.close()


def _job(client: str, n: int) -> Job:
    return Job(client, n, 1, bytes((1, 3, 0, n, 0, 1)))


def _submit(scheduler: Scheduler, queue: Queue, client: str, count: int) -> None:
    for n in range(count):
        scheduler.submit(queue, _job(client, n))


def _drain(scheduler: Scheduler) -> list[tuple[str, int]]:
    taken = []
    while (job := scheduler.take()) is not None:
        taken.append((job.client, job.tid))
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
    scheduler.submit(late, _job("late", 0))
    assert [scheduler.take().client for _ in range(2)] == ["busy", "late"]


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
