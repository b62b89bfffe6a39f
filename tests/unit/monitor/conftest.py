"""What the bus decoders' tests share: a decoder of the line's protocol, and what it heard."""
import random

import pytest

from mbgw.monitor.bus import MonitorCounters, decoder_for


class Heard:
    def __init__(self, protocol: str) -> None:
        self.counters = MonitorCounters()
        self.pairs: list[tuple[bytes, bytes]] = []
        self.events: list[tuple[str, bytes]] = []
        self.decoder = decoder_for(protocol, self.counters,
                                   lambda q, r: self.pairs.append((q, r)),
                                   lambda adu, what: self.events.append((what, adu)))

    def feed_in_pieces(self, wire: bytes, seed: int) -> None:
        """wire fed 1 to 6 bytes at a time, the cuts drawn from seed."""
        rng = random.Random(seed)
        at = 0
        while at < len(wire):
            step = rng.randint(1, 6)
            self.decoder.feed(wire[at:at + step])
            at += step


@pytest.fixture
def heard() -> Heard:
    """An RTU line's decoder."""
    return Heard("rtu")


@pytest.fixture
def ascii_heard() -> Heard:
    return Heard("ascii")
