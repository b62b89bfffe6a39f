"""A serial face (a line in master mode) whose routes reach a line in slave mode: the request
goes to that line's thread as an Exchange in its Inbox, the face writes what it answers with
the address the master asked for.  The target here is a small thread draining the Inbox (the
daemon's is slave mode's line thread); the master is raw RTU frames on a socat pty, checked
byte for byte against frames built by tests/modbus.py."""
import os
import select
import threading

import pytest

from mbgw.config.lines import LineConfig, RouteConfig
from mbgw.config.model import SerialConfig, SlaveConfig
from mbgw.config.route_plan import RouteMap
from mbgw.master.serial_face import build_face
from mbgw.routing.queue import Exchange, Inbox
from tests.harness import read_pty
from tests.modbus import read_holding, rtu

BAUD = 19200
TCPTO_MS = 300
STOUT_MS = 100
PANEL = "panel"
METERS = "meters"


def exception(address: int, function: int, code: int) -> bytes:
    return rtu(address, bytes((function | 0x80, code)))


class Target(threading.Thread):
    """Drains an Inbox and answers each exchange with answer(exchange): (reply, outcome), or
    None to hold it; held ones are answered by release().  Keeps every exchange in `got`."""

    def __init__(self, inbox: Inbox, answer) -> None:
        super().__init__(daemon=True)
        self.inbox = inbox
        self.answer = answer
        self.got: list[Exchange] = []
        self.held: list[Exchange] = []
        self.taken = threading.Condition()
        self._stop_fd = os.eventfd(0, os.EFD_NONBLOCK)

    def run(self) -> None:
        while True:
            ready = select.select([self.inbox.wake_fd, self._stop_fd], [], [])[0]
            if self._stop_fd in ready:
                return
            for exchange in self.inbox.drain():
                answered = self.answer(exchange)
                with self.taken:
                    self.got.append(exchange)
                    if answered is None:
                        self.held.append(exchange)
                    self.taken.notify_all()
                if answered is not None:
                    exchange.done(exchange, *answered)

    def wait_for(self, count: int) -> list[Exchange]:
        with self.taken:
            assert self.taken.wait_for(lambda: len(self.got) >= count, timeout=3.0), self.got
            return list(self.got)

    def stop(self) -> None:
        os.eventfd_write(self._stop_fd, 1)
        self.join()
        os.close(self._stop_fd)


@pytest.fixture
def face_with(pty_pair):
    """face_with(*routes, inboxes=..., exception=True) -> the face of line `panel` on the
    pty, started; its target line `meters` has stout STOUT_MS."""
    faces = []

    def start(*routes: RouteConfig, inboxes: dict, exception: bool = True):
        panel = LineConfig(PANEL, SerialConfig(pty_pair.gateway, baudrate=BAUD), mode="master")
        meters = LineConfig(METERS, SerialConfig("/dev/meters-not-opened", stout_ms=STOUT_MS))
        cfg = SlaveConfig(SerialConfig("/dev/serial-not-opened"), exception=exception,
                          tcpto_ms=TCPTO_MS, lines=(panel, meters), routes=routes)
        face = build_face(panel, cfg, RouteMap(routes), inboxes, None)
        faces.append(face)
        face.start()
        return face

    yield start
    for face in faces:
        face.stop()
        face.join()
        face.close()


@pytest.fixture
def target(inbox):
    targets = []

    def start(answer) -> Target:
        t = Target(inbox, answer)
        targets.append(t)
        t.start()
        return t

    yield start
    for t in targets:
        t.stop()


def to_meters(units, **rewrite) -> RouteConfig:
    return RouteConfig(1, tuple(units), face=PANEL, line=METERS, **rewrite)


def register_reply(exchange: Exchange):
    """Holding register 0 of the device at the exchange's address holds 100 + address."""
    return bytes((0x03, 2, 0, 100 + exchange.address)), "reply"


def ask(fd: int, frame: bytes, expected: bytes) -> None:
    os.write(fd, frame)
    got = read_pty(fd, len(expected))
    assert got == expected, f"got {got.hex(' ')}, expected {expected.hex(' ')}"


def test_an_offset_route_reaches_the_line_and_the_master_gets_its_own_address(
        face_with, line, inbox, target):
    t = target(register_reply)
    face_with(to_meters(range(32, 64), offset=-31), inboxes={METERS: inbox})
    ask(line, rtu(32, read_holding(0, 1)), rtu(32, bytes((0x03, 2, 0, 101))))
    ask(line, rtu(63, read_holding(0, 1)), rtu(63, bytes((0x03, 2, 0, 132))))
    first, last = t.wait_for(2)
    assert (first.source, first.address, first.pdu) == (PANEL, 1, read_holding(0, 1))
    assert (last.source, last.address) == (PANEL, 32)


def test_a_fixed_address_route(face_with, line, inbox, target):
    t = target(register_reply)
    face_with(to_meters((7, 8), address=20), inboxes={METERS: inbox})
    ask(line, rtu(8, read_holding(0, 1)), rtu(8, bytes((0x03, 2, 0, 120))))
    assert [e.address for e in t.wait_for(1)] == [20]


def test_an_unrouted_address_gets_no_answer_and_reaches_no_line(face_with, line, inbox,
                                                                  target):
    t = target(register_reply)
    face_with(to_meters((1,), offset=4), inboxes={METERS: inbox})
    # the unrouted request gets nothing: the routed one right behind it is answered first
    os.write(line, rtu(2, read_holding(0, 1)) + rtu(1, read_holding(0, 1)))
    expected = rtu(1, bytes((0x03, 2, 0, 105)))
    assert read_pty(line, len(expected) + 1) == expected
    assert [e.address for e in t.wait_for(1)] == [5]


def test_the_lines_silence_is_silence_on_the_face(face_with, line, inbox, target):
    t = target(lambda e: (None, "timeout") if e.address == 3 else register_reply(e))
    face_with(to_meters((3, 4)), inboxes={METERS: inbox})
    os.write(line, rtu(3, read_holding(0, 1)))
    t.wait_for(1)
    ask(line, rtu(4, read_holding(0, 1)), rtu(4, bytes((0x03, 2, 0, 104))))


def test_a_line_that_does_not_answer_in_time_is_0x0b_and_its_late_answer_is_dropped(
        face_with, line, inbox, target):
    t = target(lambda e: None if e.address == 3 else register_reply(e))
    face_with(to_meters((3, 4)), inboxes={METERS: inbox})
    ask(line, rtu(3, read_holding(0, 1)), exception(3, 0x03, 0x0B))
    held = t.wait_for(1)[0]
    held.done(held, bytes((0x03, 2, 0, 103)), "reply")     # late: the face has moved on
    ask(line, rtu(4, read_holding(0, 1)), rtu(4, bytes((0x03, 2, 0, 104))))


def test_without_exception_a_line_that_does_not_answer_in_time_is_silence(
        face_with, line, inbox, target):
    target(lambda e: None if e.address == 3 else register_reply(e))
    face_with(to_meters((3, 4)), inboxes={METERS: inbox}, exception=False)
    # nothing for 3: after its wait, the answer to 4 (written right behind) comes first
    expected = rtu(4, bytes((0x03, 2, 0, 104)))
    os.write(line, rtu(3, read_holding(0, 1)) + rtu(4, read_holding(0, 1)))
    assert read_pty(line, len(expected) + 1) == expected


def test_a_route_to_a_line_that_is_not_running_is_0x0a(face_with, line):
    face_with(to_meters((3,)), inboxes={})
    ask(line, rtu(3, read_holding(0, 1)), exception(3, 0x03, 0x0A))


def test_a_broadcast_never_goes_to_another_line(face_with, line, inbox, target):
    t = target(register_reply)
    face_with(to_meters((3,)), inboxes={METERS: inbox})
    os.write(line, rtu(0, bytes.fromhex("06 00 01 00 07")))
    ask(line, rtu(3, read_holding(0, 1)), rtu(3, bytes((0x03, 2, 0, 103))))
    assert [e.address for e in t.wait_for(1)] == [3]


def test_a_line_whose_inbox_comes_later_is_reached_from_then_on(face_with, line, inbox,
                                                                 target):
    inboxes: dict = {}
    face_with(to_meters((3,)), inboxes=inboxes)
    ask(line, rtu(3, read_holding(0, 1)), exception(3, 0x03, 0x0A))
    target(register_reply)
    inboxes[METERS] = inbox            # the target line has started
    ask(line, rtu(3, read_holding(0, 1)), rtu(3, bytes((0x03, 2, 0, 103))))
