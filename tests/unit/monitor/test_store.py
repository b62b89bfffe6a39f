"""MapStore: the answered values put in the table under the maps, a partial reply's part."""
from mbgw.config.monitor import MonitorMap
from mbgw.monitor.store import MapStore
from mbgw.table.memory import Table


def read(unit: int, function: int, start: int, quantity: int) -> bytes:
    return bytes([unit, function]) + start.to_bytes(2, "big") + quantity.to_bytes(2, "big")


def registers_reply(unit: int, function: int, values: list[int]) -> bytes:
    data = b"".join(v.to_bytes(2, "big") for v in values)
    return bytes([unit, function, len(data)]) + data


def test_registers_of_a_map_are_stored_at_its_table_address() -> None:
    table = Table()
    store = MapStore((MonitorMap(1, "tap", 5, 3, 100, 4, 10),), table)
    store.answered(read(5, 3, 100, 4), registers_reply(5, 3, [1, 2, 3, 4]))
    assert table.read(10, 4) == [1, 2, 3, 4]
    assert store.ages(store.stored_at[1])[1] == 0


def test_a_reply_covering_part_of_a_map_stores_that_part() -> None:
    table = Table()
    store = MapStore((MonitorMap(1, "tap", 5, 4, 100, 4, 10),), table)
    store.answered(read(5, 4, 98, 4), registers_reply(5, 4, [7, 8, 9, 10]))
    assert table.read(9, 5) == [0, 9, 10, 0, 0]


def test_other_units_functions_and_exceptions_store_nothing() -> None:
    table = Table()
    store = MapStore((MonitorMap(1, "tap", 5, 3, 0, 2, 0),), table)
    store.answered(read(6, 3, 0, 2), registers_reply(6, 3, [1, 2]))
    store.answered(read(5, 4, 0, 2), registers_reply(5, 4, [1, 2]))
    store.answered(read(5, 3, 0, 2), bytes([5, 0x83, 2]))
    assert table.read(0, 2) == [0, 0]
    assert store.ages(0.0) == {1: None}


def test_bits_are_one_register_each() -> None:
    table = Table()
    store = MapStore((MonitorMap(1, "tap", 2, 1, 0, 10, 20),), table)
    store.answered(read(2, 1, 0, 10), bytes([2, 1, 2, 0b10100101, 0b10]))
    assert table.read(20, 10) == [1, 0, 1, 0, 0, 1, 0, 1, 0, 1]
