"""The one deadline loop of the tests: what the daemon (or a peer) does on its own, after the
last event a test can see, is polled until it holds."""
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

POLL_S = 0.01


def until(condition: Callable[[], T], what: str | Callable[[], str], timeout: float) -> T:
    """condition()'s value once it is truthy.  After timeout seconds, an AssertionError
    "never <what>" (what may be a function, called then, to show the state reached)."""
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        if time.monotonic() >= deadline:
            raise AssertionError(f"never {what() if callable(what) else what}")
        time.sleep(POLL_S)
    return value
