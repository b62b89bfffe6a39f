"""SerialMaster's reply path in two steps (mbgw.slave.transaction): exchange() returns what
brought the reply and keeps no books of it; book() keeps them after the reply has gone on.
A reply that does not answer comes back with the LineTimeout (its mismatch).  A real pty pair
carries the slave's frames, written by a thread that answers what it reads."""
import os
import threading

import pytest

from mbgw.config.model import SerialConfig
from mbgw.errors import LineTimeout
from mbgw.line.serial_line import SerialLine
from mbgw.ops.counters import Counters
from mbgw.ops.device_stats import DeviceHealth
from mbgw.slave.framing import framing_for
from mbgw.slave.transaction import SerialMaster
from tests.modbus import holding_reply, read_holding, rtu

pytestmark = pytest.mark.integration

UNIT = 5
STOUT_MS = 200


@pytest.fixture
def rig(pty_pair):
    """(SerialMaster on the gateway's end, counters, answer(reply PDU)): the slave's end
    answers the next request it reads with reply PDU."""
    cfg = SerialConfig(pty_pair.gateway, baudrate=19200, stout_ms=STOUT_MS)
    counters = Counters()
    line = SerialLine(cfg, counters)
    slave = os.open(pty_pair.device, os.O_RDWR | os.O_NOCTTY)
    threads = []

    def answer(reply: bytes) -> None:
        def run() -> None:
            os.read(slave, 256)
            os.write(slave, rtu(UNIT, reply))
        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        threads.append(thread)

    yield SerialMaster(framing_for(line), cfg, counters, DeviceHealth()), counters, answer
    for thread in threads:
        thread.join(2)
    os.close(slave)
    line.close()


def test_the_reply_is_returned_before_its_books_are_kept(rig):
    master, counters, answer = rig
    answer(holding_reply(0, 2))
    got = master.exchange(bytes((UNIT,)) + read_holding(0, 2))
    assert got is not None and got.frame == bytes((UNIT,)) + holding_reply(0, 2)
    device = master.devices.get(UNIT)
    assert (device.transactions, device.replies, counters.line_busy_ns) == (1, 0, 0)
    master.book(got)
    assert device.replies == 1
    assert counters.line_busy_ns > 0


def test_a_device_exception_is_booked_as_one(rig):
    master, counters, answer = rig
    answer(b"\x83\x02")
    got = master.exchange(bytes((UNIT,)) + read_holding(0, 2))
    assert got is not None and got.frame == bytes((UNIT,)) + b"\x83\x02"
    master.book(got)
    assert counters.device_exceptions == 1
    assert master.devices.get(UNIT).exceptions == {2: 1}


def test_a_reply_that_does_not_answer_comes_with_the_timeout(rig):
    master, counters, answer = rig
    answer(holding_reply(0, 1))                 # one register where two were asked for
    with pytest.raises(LineTimeout) as raised:
        master.exchange(bytes((UNIT,)) + read_holding(0, 2))
    assert raised.value.mismatch == holding_reply(0, 1)
    assert master.devices.get(UNIT).timeouts == 1


def test_a_timeout_with_no_reply_at_all_has_no_mismatch(rig):
    master, _, _ = rig
    with pytest.raises(LineTimeout) as raised:
        master.exchange(bytes((UNIT,)) + read_holding(0, 2))
    assert raised.value.mismatch is None
