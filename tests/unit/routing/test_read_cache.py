"""A line's read cache (issue 27): coalescing by arrival, fresh data within ttl (sub-ranges
too), stale data after a failure, invalidation by writes, exception replies shared but never
kept, the figures."""
from mbgw.config.cache import CacheRule
from mbgw.routing.cache import ReadCache, is_read

MS = 1_000_000
TTL = CacheRule(ttl_ms=500, serve_stale_ms=5000)
COALESCE = CacheRule()


def read(address: int, function: int, start: int, count: int) -> bytes:
    return bytes((address, function)) + start.to_bytes(2, "big") + count.to_bytes(2, "big")


def registers(*values: int) -> bytes:
    data = b"".join(v.to_bytes(2, "big") for v in values)
    return bytes((3, len(data))) + data


def served(cache: ReadCache, reply: bytes | None) -> tuple[bytes, str] | None:
    """What answer() or stale() found, with the trace's outcome of it."""
    return None if reply is None else (reply, cache.outcome())


def filled(adu: bytes, reply: bytes, end_ns: int) -> ReadCache:
    cache = ReadCache()
    cache.answered(adu, reply, end_ns)
    return cache


def test_a_read_that_arrived_before_the_answer_ended_shares_it_even_without_ttl():
    adu = read(3, 3, 0, 2)
    cache = filled(adu, registers(7, 8), end_ns=100 * MS)
    assert served(cache, cache.answer(COALESCE, adu, 99 * MS, 101 * MS)) == \
        (registers(7, 8), "coalesced")
    assert cache.answer(COALESCE, adu, 101 * MS, 102 * MS) is None     # arrived after


def test_an_exception_reply_is_shared_but_never_kept():
    adu = read(3, 3, 0, 2)
    cache = filled(adu, b"\x83\x02", end_ns=100 * MS)
    assert served(cache, cache.answer(TTL, adu, 99 * MS, 101 * MS)) == (b"\x83\x02", "coalesced")
    assert cache.answer(TTL, adu, 100 * MS + 1, 101 * MS) is None
    assert cache.stale(TTL, adu, 101 * MS) is None


def test_fresh_data_is_served_within_ttl_with_its_age():
    adu = read(3, 3, 10, 2)
    cache = filled(adu, registers(1, 2), end_ns=100 * MS)
    assert served(cache, cache.answer(TTL, adu, 200 * MS, 599 * MS)) == \
        (registers(1, 2), "cached 499 ms")
    assert cache.answer(TTL, adu, 200 * MS, 601 * MS) is None


def test_a_sub_range_of_registers_and_of_bits():
    cache = filled(read(3, 3, 10, 4), registers(1, 2, 3, 4), end_ns=100 * MS)
    assert cache.answer(TTL, read(3, 3, 11, 2), 200 * MS, 200 * MS) == registers(2, 3)
    assert cache.answer(TTL, read(3, 3, 12, 3), 200 * MS, 200 * MS) is None   # not within
    assert cache.answer(TTL, read(3, 4, 11, 2), 200 * MS, 200 * MS) is None   # FC 4
    assert cache.answer(TTL, read(4, 3, 11, 2), 200 * MS, 200 * MS) is None   # unit 4
    coils = filled(read(3, 1, 0, 10), bytes((1, 2, 0b1011_0101, 0b11)), end_ns=100 * MS)
    assert coils.answer(TTL, read(3, 1, 2, 8), 200 * MS, 200 * MS) == \
        bytes((1, 1, 0b1110_1101))
    assert coils.answer(TTL, read(3, 1, 7, 3), 200 * MS, 200 * MS) == bytes((1, 1, 0b111))


def test_stale_data_up_to_serve_stale():
    adu = read(3, 3, 0, 2)
    cache = filled(adu, registers(5, 6), end_ns=100 * MS)
    assert served(cache, cache.stale(TTL, adu, 5099 * MS)) == (registers(5, 6), "stale 4999 ms")
    assert cache.stale(TTL, adu, 5101 * MS) is None
    assert cache.stale(CacheRule(ttl_ms=500), adu, 200 * MS) is None    # off unless set


def test_a_write_drops_what_it_overlaps_of_its_kind_only():
    holding, inputs, coils = read(3, 3, 10, 4), read(3, 4, 10, 4), read(3, 1, 10, 4)
    cache = ReadCache()
    for adu, reply in ((holding, registers(1, 2, 3, 4)), (inputs, b"\x04\x08" + bytes(8)),
                       (coils, b"\x01\x01\x0f")):
        cache.answered(adu, reply, 100 * MS)
    cache.written(bytes((3, 0x10, 0, 13, 0, 1, 2, 0, 9)))   # FC 16 at 13
    assert cache.answer(TTL, holding, 200 * MS, 200 * MS) is None
    assert cache.answer(TTL, holding, 50 * MS, 200 * MS) is None       # nor coalesced
    assert cache.answer(TTL, inputs, 200 * MS, 200 * MS) is not None   # only ages
    assert cache.answer(TTL, coils, 200 * MS, 200 * MS) is not None
    cache.written(bytes((3, 0x05, 0, 9, 0xFF, 0)))          # FC 5 just before: no overlap
    assert cache.answer(TTL, coils, 200 * MS, 200 * MS) is not None
    cache.written(bytes((0, 0x0F, 0, 12, 0, 1, 1, 1)))      # a broadcast FC 15
    assert cache.answer(TTL, coils, 200 * MS, 200 * MS) is None


def test_fc23_invalidates_by_its_write_range():
    cache = filled(read(3, 3, 100, 2), registers(1, 2), end_ns=100 * MS)
    # read 0..1, write 101..101
    cache.written(bytes((3, 0x17, 0, 0, 0, 2, 0, 101, 0, 1, 2, 0, 0)))
    assert cache.answer(TTL, read(3, 3, 100, 2), 200 * MS, 200 * MS) is None


def test_the_figures_by_unit_and_the_ages():
    adu = read(3, 3, 0, 2)
    cache = ReadCache()
    cache.missed(adu)
    cache.answered(adu, registers(1, 2), 100 * MS)
    cache.answer(TTL, adu, 99 * MS, 100 * MS)
    cache.answer(TTL, adu, 101 * MS, 103 * MS)
    cache.stale(TTL, adu, 900 * MS)
    status = cache.status()
    assert status["units"] == {"3": {"hits": 1, "coalesced": 1, "misses": 1,
                                     "stale_served": 1}}
    assert sum(status["ages"]["counts"]) == 2 and status["ages"]["sum_ms"] == 803


def test_an_exact_hit_and_a_sub_range_hit_keep_the_same_books():
    whole, part = read(3, 3, 0, 4), read(3, 3, 1, 2)
    cache = filled(whole, registers(1, 2, 3, 4), end_ns=100 * MS)
    assert served(cache, cache.answer(TTL, part, 200 * MS, 104 * MS)) == \
        (registers(2, 3), "cached 4 ms")
    assert served(cache, cache.answer(TTL, whole, 200 * MS, 107 * MS)) == \
        (registers(1, 2, 3, 4), "cached 7 ms")
    status = cache.status()
    assert status["units"]["3"]["hits"] == 2
    assert sum(status["ages"]["counts"]) == 2 and status["ages"]["sum_ms"] == 11


def test_clear_forgets_everything():
    adu = read(3, 3, 0, 2)
    cache = filled(adu, registers(1, 2), end_ns=100 * MS)
    cache.clear()
    assert cache.answer(TTL, adu, 99 * MS, 101 * MS) is None


def test_what_is_a_cacheable_read():
    assert is_read(read(3, 3, 0, 2))
    assert not is_read(read(0, 3, 0, 2))
    assert not is_read(bytes((3, 6, 0, 1, 0, 5)))
