import pytest

from tests.integration.slave.test_connections import Sockets


@pytest.fixture(params=[(), ("--no-shortcut",)], ids=["shortcut", "no-shortcut"])
def shortcut_both_ways(request) -> tuple[str, ...]:
    """The gateway's options for one of two runs of the test: with the idle line's shortcut
    (a request that finds the line idle goes on it from C, csrc/forward.c) and without it
    (every request through the queue, SerialMaster.transact)."""
    return request.param


@pytest.fixture
def sockets():
    """Sockets that are closed after the test (sockets.connect(port))."""
    opened = Sockets()
    yield opened
    for sock in opened:
        sock.close()
