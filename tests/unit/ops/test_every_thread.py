"""systemd's watchdog over every line thread of a daemon (mbgw.ops.service.EveryThread): it
turns while each line thread does, and the lines are asked anew each time (a reload adds and
removes them)."""
from types import SimpleNamespace

from mbgw.ops.service import EveryThread


def thread(heartbeat: float, turn_limit_s: float, alive: bool = True) -> SimpleNamespace:
    return SimpleNamespace(heartbeat=heartbeat, turn_limit_s=turn_limit_s,
                           is_alive=lambda: alive)


def test_the_oldest_heartbeat_and_the_longest_turn_of_every_line():
    lines = [thread(10.0, 1.0), thread(4.0, 3.0), thread(7.0, 2.0)]
    every = EveryThread(lambda: lines)
    assert (every.heartbeat, every.turn_limit_s, every.is_alive()) == (4.0, 3.0, True)
    lines.append(thread(1.0, 0.5, alive=False))        # a line a reload added, ended
    assert (every.heartbeat, every.is_alive()) == (1.0, False)
    del lines[1:]                                      # removed again
    assert (every.heartbeat, every.turn_limit_s, every.is_alive()) == (10.0, 1.0, True)
