"""The line queue (mbgw.scheduler): fair between clients, in order within a client, and an
eventfd that wakes the line thread only when it went to sleep on an empty queue."""
import os

import pytest

from mbgw.scheduler import Job, Queue, Scheduler


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


def test_submit_does_not_wake_a_line_that_is_not_sleeping(scheduler):
    _submit(scheduler, Queue(), "a", 3)
    assert not _woken(scheduler)


def test_submit_after_an_empty_take_wakes_the_line(scheduler):
    assert scheduler.take() is None          # the line goes to sleep
    scheduler.submit(Queue(), _job("a", 0))
    assert os.eventfd_read(scheduler.wake_fd) == 1


def test_only_the_first_submit_after_sleeping_wakes_the_line(scheduler):
    queue = Queue()
    assert scheduler.take() is None
    _submit(scheduler, queue, "a", 3)
    assert os.eventfd_read(scheduler.wake_fd) == 1
    assert not _woken(scheduler)


def test_a_take_that_finds_work_does_not_arm_the_wakeup(scheduler):
    queue = Queue()
    scheduler.submit(queue, _job("a", 0))
    assert scheduler.take() is not None
    scheduler.submit(queue, _job("a", 1))
    assert not _woken(scheduler)


def test_wake_always_signals(scheduler):
    scheduler.wake()
    assert _woken(scheduler)
    assert not _woken(scheduler)


# --- a request on an idle line is put on it by the submitting thread -----------------------

class Starter:
    """The line worker's start_now: records what it was asked to start; accepts or not."""

    def __init__(self, accept: bool = True) -> None:
        self.accept = accept
        self.asked: list[tuple[str, int]] = []

    def __call__(self, job: Job) -> bool:
        self.asked.append((job.client, job.tid))
        return self.accept


@pytest.fixture
def starter(scheduler):
    scheduler.start_now = Starter()
    return scheduler.start_now


def _park(scheduler: Scheduler) -> None:
    assert scheduler.take() is None
    assert scheduler.park()


def test_a_request_for_a_parked_line_is_started_at_once_and_the_line_woken(scheduler, starter):
    _park(scheduler)
    scheduler.submit(Queue(), _job("a", 7))
    assert starter.asked == [("a", 7)]
    assert os.eventfd_read(scheduler.wake_fd) == 1
    assert scheduler.unpark()                    # the line thread learns of it on waking
    job = scheduler.take()
    assert (job.client, job.tid, job.started) == ("a", 7, True)
    assert scheduler.depth == 0 and scheduler.take() is None


def test_only_one_request_is_started_the_next_ones_queue(scheduler, starter):
    _park(scheduler)
    queue = Queue()
    _submit(scheduler, queue, "a", 3)
    assert starter.asked == [("a", 0)]
    assert scheduler.unpark()
    assert [(j.client, j.tid, j.started) for j in iter(scheduler.take, None)] == \
        [("a", 0, True), ("a", 1, False), ("a", 2, False)]


def test_a_declined_start_queues_the_request_and_wakes_the_line(scheduler, starter):
    starter.accept = False
    _park(scheduler)
    scheduler.submit(Queue(), _job("a", 0))
    assert os.eventfd_read(scheduler.wake_fd) == 1
    assert not scheduler.unpark()
    job = scheduler.take()
    assert (job.tid, job.started) == (0, False)


def test_once_a_request_waits_the_next_one_is_not_started_ahead_of_it(scheduler, starter):
    starter.accept = False
    _park(scheduler)
    scheduler.submit(Queue(), _job("a", 0))
    starter.accept = True
    scheduler.submit(Queue(), _job("b", 0))        # the line is still parked: it has not woken
    assert starter.asked == [("a", 0)]
    assert not scheduler.unpark()
    assert _drain(scheduler) == [("a", 0), ("b", 0)]


def test_nothing_is_started_while_the_line_is_busy(scheduler, starter):
    _submit(scheduler, Queue(), "a", 1)
    assert scheduler.take() is not None            # busy with it, not parked
    _submit(scheduler, Queue(), "b", 1)
    assert starter.asked == []
    assert _drain(scheduler) == [("b", 0)]


def test_nothing_is_started_after_the_line_unparked(scheduler, starter):
    _park(scheduler)
    assert not scheduler.unpark()                  # woken by unsolicited input, say
    _submit(scheduler, Queue(), "a", 1)
    assert starter.asked == []
    assert _drain(scheduler) == [("a", 0)]


def test_the_line_does_not_park_while_work_waits(scheduler, starter):
    _submit(scheduler, Queue(), "a", 1)
    assert not scheduler.park()
    assert _drain(scheduler) == [("a", 0)]
