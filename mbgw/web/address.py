"""The console's listening address, as [web] listen and --web write it."""
from mbgw.errors import ConfigError


def parse_listen(text: str) -> tuple[str | None, int]:
    """'ADDR:PORT', '[IPV6]:PORT' or ':PORT' (every address) -> (host or None, port)."""
    host, sep, port = text.rpartition(":")
    if not sep:
        raise ConfigError(f"{text!r}: not ADDR:PORT (e.g. 127.0.0.1:8080)")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise ConfigError(f"{text!r}: write an IPv6 address in brackets, [ADDR]:PORT")
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"{text!r}: port {port!r} is not 1..65535")
    return host or None, int(port)
