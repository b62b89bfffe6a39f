"""A histogram's buckets as prometheus_client takes them, from counts per bound."""
from collections.abc import Iterable

from prometheus_client.utils import floatToGoString


def cumulative_buckets(bounds_ms: Iterable[float], counts: Iterable[int]) -> list[tuple[str, int]]:
    """(upper bound in seconds, count up to it) of each bucket, +Inf last: counts has one more
    than bounds_ms, the count over the last bound."""
    bounds = [floatToGoString(ms / 1000) for ms in bounds_ms] + ["+Inf"]
    cumulative, buckets = 0, []
    for bound, n in zip(bounds, counts, strict=True):
        cumulative += n
        buckets.append((bound, cumulative))
    return buckets
