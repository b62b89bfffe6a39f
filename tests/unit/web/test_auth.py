"""The console's sessions and login rate limit (mbgw/web/auth.py) on a clock the test turns:
idle and absolute expiry, the per-role cap, the failures window per client address."""
import pytest

from mbgw.web.auth import (
    ABSOLUTE_S,
    FAILURES_PER_WINDOW,
    IDLE_ENV,
    IDLE_S,
    LOGIN_WINDOW_S,
    SESSIONS_PER_ROLE,
    LoginLimit,
    Sessions,
)


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now

    def turn(self, seconds: float) -> None:
        self.now += seconds


@pytest.fixture
def clock():
    return Clock()


@pytest.fixture
def sessions(clock, monkeypatch):
    monkeypatch.delenv(IDLE_ENV, raising=False)
    return Sessions(clock=clock)


# --- sessions ---

def test_a_session_is_found_by_its_token_and_nothing_else(sessions):
    token, session = sessions.open("admin")
    other, _ = sessions.open("admin")
    assert token != other and session.role == "admin" and session.csrf
    assert sessions.get(token) is session
    assert sessions.get(None) is None and sessions.get("") is None
    assert sessions.get(token + "x") is None


def test_a_session_idle_longer_than_the_idle_time_is_over_and_forgotten(sessions, clock):
    token, _ = sessions.open("user")
    clock.turn(IDLE_S)
    assert sessions.get(token) is not None            # exactly the idle time: still on
    clock.turn(IDLE_S + 0.001)
    assert sessions.get(token) is None
    clock.now -= 10 * IDLE_S                          # forgotten, not merely out of time
    assert sessions.get(token) is None


def test_each_use_starts_the_idle_time_again(sessions, clock):
    token, _ = sessions.open("user")
    for _ in range(5):
        clock.turn(IDLE_S * 0.9)
        assert sessions.get(token) is not None


def test_a_session_in_use_ends_all_the_same_at_its_absolute_age(sessions, clock):
    token, _ = sessions.open("admin")
    step = IDLE_S / 2
    while clock.now + step - 1000.0 <= ABSOLUTE_S:
        clock.turn(step)
        assert sessions.get(token) is not None
    clock.turn(step)
    assert sessions.get(token) is None


def test_the_idle_time_comes_from_the_environment_for_tests(clock, monkeypatch):
    monkeypatch.setenv(IDLE_ENV, "2.5")
    sessions = Sessions(clock=clock)
    token, _ = sessions.open("user")
    clock.turn(2.6)
    assert sessions.get(token) is None


def test_a_roles_sessions_are_capped_its_oldest_ending_and_no_other_roles(sessions):
    user, _ = sessions.open("user")
    admins = [sessions.open("admin")[0] for _ in range(SESSIONS_PER_ROLE)]
    newest, _ = sessions.open("admin")
    assert sessions.get(admins[0]) is None
    assert all(sessions.get(token) is not None for token in admins[1:])
    assert sessions.get(newest) is not None and sessions.get(user) is not None


def test_close_ends_one_session_clear_all(sessions):
    a, _ = sessions.open("admin")
    b, _ = sessions.open("user")
    sessions.close(a)
    sessions.close(None)
    sessions.close("unknown")
    assert sessions.get(a) is None and sessions.get(b) is not None
    sessions.clear()
    assert sessions.get(b) is None


# --- the login rate limit ---

def test_failures_up_to_the_limit_are_let_in_and_the_next_is_refused(clock):
    limit = LoginLimit(clock=clock)
    for _ in range(FAILURES_PER_WINDOW):
        assert limit.attempt("192.0.2.1") == 0
        clock.turn(1)
    assert limit.attempt("192.0.2.1") > 0
    assert limit.attempt("192.0.2.2") == 0            # another address is on its own


def test_the_wait_a_refusal_names_is_enough_and_not_more_than_the_window(clock):
    limit = LoginLimit(clock=clock)
    for _ in range(FAILURES_PER_WINDOW):
        limit.attempt("192.0.2.1")
    clock.turn(LOGIN_WINDOW_S / 2)
    wait = limit.attempt("192.0.2.1")
    assert LOGIN_WINDOW_S / 2 <= wait <= LOGIN_WINDOW_S / 2 + 1
    clock.turn(wait)
    assert limit.attempt("192.0.2.1") == 0


def test_a_refused_attempt_does_not_prolong_the_wait(clock):
    limit = LoginLimit(clock=clock)
    for _ in range(FAILURES_PER_WINDOW):
        limit.attempt("192.0.2.1")
    first = limit.attempt("192.0.2.1")
    clock.turn(10)
    assert limit.attempt("192.0.2.1") == first - 10


def test_failures_older_than_the_window_no_longer_count(clock):
    limit = LoginLimit(clock=clock)
    for _ in range(FAILURES_PER_WINDOW - 1):
        limit.attempt("192.0.2.1")
    clock.turn(LOGIN_WINDOW_S + 0.001)
    for _ in range(FAILURES_PER_WINDOW):
        assert limit.attempt("192.0.2.1") == 0
    assert limit.attempt("192.0.2.1") > 0


def test_a_success_forgets_the_addresses_failures(clock):
    limit = LoginLimit(clock=clock)
    for _ in range(FAILURES_PER_WINDOW - 1):
        limit.attempt("192.0.2.1")
    limit.attempt("192.0.2.1")
    limit.succeeded("192.0.2.1")
    for _ in range(FAILURES_PER_WINDOW):
        assert limit.attempt("192.0.2.1") == 0


def test_attempts_at_once_count_before_their_passwords_are_checked(clock):
    limit = LoginLimit(clock=clock)
    let_in = [limit.attempt("192.0.2.1") for _ in range(3 * FAILURES_PER_WINDOW)]
    assert let_in.count(0) == FAILURES_PER_WINDOW

