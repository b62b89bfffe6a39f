"""The `cache` key of a line in slave mode (`[serial]`, `[[line]]`) and of a `[[route]]`:
`cache = { ttl = 500, serve-stale = 5000 }` in the file, `--cache ttl=500,serve-stale=5000`
on the command line.  What it does is mbgw.routing.cache's."""
from dataclasses import dataclass
from typing import Literal

from mbgw.errors import ConfigError

CACHE_MS_RANGE = (0, 3_600_000)    # ttl and serve-stale, ms
CACHE_FIELDS = {"ttl": "ttl_ms", "serve-stale": "serve_stale_ms"}
CACHE_EXAMPLE = "{ ttl = 500, serve-stale = 5000 }"


@dataclass(frozen=True)
class CacheRule:
    """A read within data read less than ttl ago is answered from memory (0: only reads
    arriving while an identical one is under way share its answer); after its own
    transaction failed, from data less than serve-stale old (0: never)."""
    ttl_ms: int = 0
    serve_stale_ms: int = 0

    def __post_init__(self) -> None:
        low, high = CACHE_MS_RANGE
        for name, attribute in CACHE_FIELDS.items():
            value = getattr(self, attribute)
            if not low <= value <= high:
                raise ConfigError(f"{name} {value}: out of range {low}..{high} ms")

    @property
    def text(self) -> str:
        """As --cache takes it."""
        return f"ttl={self.ttl_ms},serve-stale={self.serve_stale_ms}"

    @property
    def fields(self) -> dict:
        """As the file's inline table."""
        return {"ttl": self.ttl_ms, "serve-stale": self.serve_stale_ms}


# A route's `cache`: its own rule, False (off), or None (not given: its line's).
RouteCache = CacheRule | Literal[False] | None


def parse_cache(value: object) -> CacheRule | None:
    """The file's table ({ ttl = 500, serve-stale = 5000 }), --cache's text
    ("ttl=500,serve-stale=5000"), or false/"off" (None).  ConfigError says what is wrong."""
    if value is False or value in ("off", "false"):
        return None
    if isinstance(value, str):
        value = _from_text(value)
    if not isinstance(value, dict):
        raise ConfigError(f"expected a table such as {CACHE_EXAMPLE}, or false; got {value!r}")
    unknown = [k for k in value if k not in CACHE_FIELDS]
    if unknown:
        raise ConfigError(f"unknown key {unknown[0]!r}; expected ttl and serve-stale (ms)")
    given = {}
    for name, ms in value.items():
        if not isinstance(ms, int) or isinstance(ms, bool):
            raise ConfigError(f"{name}: expected an integer (ms), got {ms!r}")
        given[CACHE_FIELDS[name]] = ms
    return CacheRule(**given)


def _from_text(text: str) -> dict:
    fields: dict = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, number = part.partition("=")
        if not sep or not number.strip().isdigit():
            raise ConfigError(f"{part!r}: expected NAME=MS, e.g. ttl=500,serve-stale=5000")
        fields[name.strip()] = int(number)
    return fields
