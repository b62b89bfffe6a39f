import pytest

from tests.harness import factory
from tests.integration.ops.test_trace_raw import Trace


@pytest.fixture
def trace():
    """trace(gw, *args) -> a running `mbgw trace`; stopped after the test."""
    yield from factory(Trace, Trace.stop)
