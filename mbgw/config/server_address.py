"""A Modbus TCP server's address as the file gives it (a scenario's or a route's `server`):
"host", "host:port", "[v6]:port" or a bare IPv6 address, and the ports it defaults to."""
import re

from mbgw.errors import ConfigError

DEFAULT_SERVER_PORT = 502
DEFAULT_TLS_SERVER_PORT = 802      # Modbus/TCP Security


def parse_server(text: str, default_port: int = DEFAULT_SERVER_PORT) -> str:
    """"host", "host:port", "[v6]:port" or a bare IPv6 address -> "host:port" ("[v6]:port")."""
    host, port = split_server(text, default_port)
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def split_server(text: str, default_port: int = DEFAULT_SERVER_PORT) -> tuple[str, int]:
    """(host, port) of a server; ConfigError when it is not one."""
    text = text.strip()
    port_text = None
    if text.startswith("["):
        match = re.fullmatch(r"\[([^\]]+)\](?::(\d+))?", text)
        if not match:
            raise ConfigError(f"{text!r}: expected [IPv6 address]:port")
        host, port_text = match[1], match[2]
    elif text.count(":") == 1:
        host, port_text = text.split(":")
    else:
        host = text                    # a name, IPv4, or a bare IPv6 address
    if not host or not re.fullmatch(r"[A-Za-z0-9._:%-]+", host):
        raise ConfigError(f"{text!r}: expected an IP address or a host name, then :port")
    if port_text is None:
        return host, default_port
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ConfigError(f"{text!r}: port {port_text!r} out of range 1..65535")
    return host, int(port_text)
