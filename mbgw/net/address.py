"""Socket addresses as mbgw writes and reads them: HOST:PORT, [IPV6]:PORT."""
from mbgw.errors import ConfigError


def format_address(address) -> str:
    """A socket address ((host, port, ...)) as HOST:PORT, an IPv6 host in brackets."""
    host, port = address[:2]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def parse_host_port(text: str, what: str = "", example: str = "") -> tuple[str | None, int]:
    """'ADDR:PORT', '[IPV6]:PORT' or ':PORT' (every address) -> (host or None, port).  Raises
    ConfigError; its message begins with what (the option, when it names one) and says
    example after a text that is not ADDR:PORT at all."""
    said = f"{what} {text!r}" if what else repr(text)
    host, sep, port = text.rpartition(":")
    if not sep:
        raise ConfigError(f"{said}: not ADDR:PORT" + (f" (e.g. {example})" if example else ""))
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise ConfigError(f"{said}: write an IPv6 address in brackets, [ADDR]:PORT")
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"{said}: port {port!r} is not 1..65535")
    return host or None, int(port)
