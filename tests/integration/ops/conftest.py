import pytest

from tests.integration.ops.test_trace_raw import Trace


@pytest.fixture
def trace():
    """trace(gw, *args) -> a running `mbgw trace`; stopped after the test."""
    started = []

    def start(gw, *args: str) -> Trace:
        t = Trace(gw, *args)
        started.append(t)
        return t
    yield start
    for t in started:
        t.stop()
