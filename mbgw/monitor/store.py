"""The answered values of a listen-only line put in the exchange table under its
`[[monitor]]` maps, and when each map was last stored (its age in status)."""
import time
from collections import defaultdict

from mbgw.config.monitor import MonitorMap

REGISTER_FUNCTIONS = (3, 4)


class MapStore:
    def __init__(self, maps: tuple[MonitorMap, ...], table) -> None:
        """maps: this line's maps; table: the exchange table (mbgw.table.memory.Table)."""
        self._table = table
        self.maps = maps
        self._maps: dict[tuple[int, int], list[MonitorMap]] = defaultdict(list)
        for m in maps:
            self._maps[m.unit, m.function].append(m)
        self.stored_at: dict[int, float] = {}     # map index: monotonic time of its last store

    def answered(self, request: bytes, reply: bytes) -> None:
        """A request ADU and the reply ADU that answers it (no CRC)."""
        maps = self._maps.get((request[0], request[1]))
        if not maps or reply[1] & 0x80 or len(request) < 6:
            return
        start = int.from_bytes(request[2:4], "big")
        quantity = int.from_bytes(request[4:6], "big")
        data = reply[3:]
        for m in maps:
            first = max(start, m.address)
            end = min(start + quantity, m.address + m.quantity)
            if first >= end:
                continue
            values = _values(m, data, first - start, end - first)
            self._table.write(m.table + first - m.address, values)
            self.stored_at[m.index] = time.monotonic()

    def ages(self, now: float) -> dict[int, float | None]:
        """Each map's age in seconds (None: never stored)."""
        return {index: None if index not in self.stored_at else now - self.stored_at[index]
                for maps in self._maps.values() for index in (m.index for m in maps)}


def _values(m: MonitorMap, data: bytes, skip: int, count: int) -> list[int]:
    if m.function in REGISTER_FUNCTIONS:
        return [int.from_bytes(data[2 * i:2 * i + 2], "big") for i in range(skip, skip + count)]
    return [data[i // 8] >> (i % 8) & 1 for i in range(skip, skip + count)]
