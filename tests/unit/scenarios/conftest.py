import pytest

from mbgw.table.memory import Table


class Clock:
    """A virtual clock for the engine's schedule: the test moves `now`."""
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


@pytest.fixture
def table():
    return Table()


@pytest.fixture
def clock():
    return Clock()
