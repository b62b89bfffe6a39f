"""A request handed to a target on another thread (mbgw.routing.queue): the target's Inbox,
and a face's AnswerWait for the answer, with its deadline, its late answers and its stop."""
import os
import select
import time

import pytest

from mbgw.errors import Interrupted
from mbgw.routing.queue import AnswerWait, Exchange

REQUEST = bytes((0x03, 0, 0, 0, 1))
REPLY = bytes((0x03, 2, 0, 42))
FAR_NS = 60 * 10**9


def readable(fd: int) -> bool:
    return bool(select.select([fd], [], [], 0)[0])


class Target:
    """An inbox whose target answers each exchange at once with `reply`, or keeps it (None)."""

    def __init__(self, reply: bytes | None) -> None:
        self.reply = reply
        self.got: list[Exchange] = []

    def submit(self, exchange: Exchange) -> None:
        self.got.append(exchange)
        if self.reply is not None:
            exchange.done(exchange, self.reply, "reply")


def test_an_inbox_hands_over_in_order_and_rings_while_some_wait(inbox):
    assert not readable(inbox.wake_fd)
    first, second = (Exchange("panel", a, REQUEST, 0, lambda *_: None) for a in (1, 2))
    inbox.submit(first)
    inbox.submit(second)
    assert readable(inbox.wake_fd)
    assert inbox.drain() == [first, second]
    assert not readable(inbox.wake_fd)
    assert inbox.drain() == []


def test_the_targets_answer_is_the_askers(wake_fd):
    wait = AnswerWait("panel", wake_fd, lambda: False)
    target = Target(REPLY)
    try:
        answer = wait.ask(target, 7, REQUEST, 1234, time.monotonic_ns() + FAR_NS)
    finally:
        wait.close()
    assert answer == (REPLY, "reply")
    [exchange] = target.got
    assert (exchange.source, exchange.address, exchange.pdu, exchange.received_ns) == \
        ("panel", 7, REQUEST, 1234)


def test_no_answer_by_the_deadline_is_none_and_the_late_answer_is_never_taken(wake_fd, inbox):
    wait = AnswerWait("panel", wake_fd, lambda: False)
    try:
        assert wait.ask(inbox, 7, REQUEST, 0, time.monotonic_ns()) is None
        [late] = inbox.drain()
        late.done(late, bytes((0x03, 2, 0, 99)), "reply")      # after the face gave up
        assert wait.ask(Target(REPLY), 7, REQUEST, 0, time.monotonic_ns() + FAR_NS) == \
            (REPLY, "reply")
    finally:
        wait.close()


def test_stopping_ends_the_wait(wake_fd):
    wait = AnswerWait("panel", wake_fd, lambda: True)
    os.eventfd_write(wake_fd, 1)
    try:
        with pytest.raises(Interrupted):
            wait.ask(Target(None), 7, REQUEST, 0, time.monotonic_ns() + FAR_NS)
    finally:
        wait.close()


def test_a_wake_up_that_is_no_stop_is_taken_and_the_wait_goes_on(wake_fd):
    target = Target(None)

    def stopping() -> bool:
        # the face is told of a new configuration while it waits; the answer comes after
        [exchange] = target.got
        exchange.done(exchange, REPLY, "reply")
        return False

    wait = AnswerWait("panel", wake_fd, stopping)
    os.eventfd_write(wake_fd, 1)
    try:
        assert wait.ask(target, 7, REQUEST, 0, time.monotonic_ns() + FAR_NS) == (REPLY, "reply")
    finally:
        wait.close()
    assert not readable(wake_fd)
