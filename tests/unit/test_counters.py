"""Counters that both the asyncio thread and the line thread count lose nothing."""
import sys
import threading

import pytest

from mbgw.counters import Counters


@pytest.fixture
def eager_thread_switching():
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)          # switch threads as often as CPython will
    yield
    sys.setswitchinterval(interval)


def test_two_threads_adding_to_one_counter_lose_no_count(eager_thread_switching):
    counters = Counters()
    per_thread = 100_000

    def count() -> None:
        for _ in range(per_thread):
            counters.add("replies")

    threads = [threading.Thread(target=count) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert counters.replies == 2 * per_thread
