"""What a daemon would refuse at start in settings whose every value is well-formed: the
files it loads (TLS certificates and keys, the table's file) and the addresses it listens on,
looked at without opening anything for good.  `mbgw run` itself, check-config, `config set`,
the web console's Set and Upload and a reload all call problems() before anything is
written or applied, so none of them passes what the start refuses.

Each check is one function of CHECKS, taking the mode's settings (SlaveConfig, MasterConfig,
TransparentModeConfig) and giving its problems, each naming the file's key first
("tls.key: ..."): another check is one more function there.  A port another program holds is
not a problem of the settings: the start fails on it (exit status 1) and systemd tries again."""
import ipaddress
import os
import re
import socket
from collections.abc import Callable
from pathlib import Path

from mbgw.config.model import MasterConfig
from mbgw.errors import ConfigError
from mbgw.net.tls import check_pair, client_context, server_context


def problems(cfg) -> list[str]:
    """Every problem of the settings, each "group.key: why"; [] when the start would go on."""
    found: list[str] = []
    for check in CHECKS:
        found += check(cfg)
    return found


def _refused(check: Callable[[], object]) -> list[str]:
    try:
        check()
    except ConfigError as err:
        return [_keyed(str(err))]
    return []


_OPTION_FIRST = re.compile(r"^(tls|web)[-.]([a-z-]+) ")    # "tls-crl /x: ...", "tls.cert /x: ..."


def _keyed(message: str) -> str:
    """The file's key first, as every problem names it: "tls.crl: /x: ..."."""
    return _OPTION_FIRST.sub(lambda m: f"{m[1]}.{m[2]}: ", message, count=1)


def tls_files(cfg) -> list[str]:
    """[tls] cert, key and ca: readable, valid now, the key the certificate's, the CA usable."""
    tls = getattr(cfg, "tls", None)
    if tls is None or not tls.enabled or not _tls_served(cfg):
        return []
    return _refused(lambda: server_context(tls, log_expiry=False))


def client_tls_files(cfg) -> list[str]:
    """[tls] client-cert, client-key and server-ca, as the connections to servers load them."""
    upstream = getattr(cfg, "upstream_tls", None)
    if upstream is None or not upstream.enabled:
        return []
    return _refused(lambda: client_context(upstream))


def web_files(cfg) -> list[str]:
    """[web] cert and key (HTTPS): readable, valid now, going together."""
    web = cfg.web
    if web.listen is None or web.cert is None or web.key is None:
        return []
    return _refused(lambda: check_pair(("web.cert", web.cert), ("web.key", web.key)))


def listen_hosts(cfg) -> list[str]:
    """The hosts of [web] listen and [general] metrics: an IP address, or a name this machine
    resolves (the start would fail on "Name or service not known")."""
    found = []
    for label, address in (("web.listen", cfg.web.listen), ("general.metrics", cfg.metrics)):
        host = _host_port(address)[0] if address else None
        if host is not None and not _resolves(host):
            found.append(f"{label}: {host!r} in {address!r} is not an IP address, nor a name "
                         f"this machine resolves")
    return found


def distinct_ports(cfg) -> list[str]:
    """Two of the daemon's listeners on one port (and an address both take) would fail the
    start with "address already in use"."""
    found: list[str] = []
    taken: list[tuple[str, str | None, int]] = []
    for label, host, port in _listeners(cfg):
        other = next((t for t in taken if t[2] == port and _overlap(t[1], host)), None)
        if other is not None:
            found.append(f"{label}: port {port} is {other[0]}'s already")
        else:
            taken.append((label, host, port))
    return found


def table_file(cfg) -> list[str]:
    """[table] persist: when it exists, a file that can be read (else the start refuses it).
    A directory not there yet is no refusal: the daemon runs on, reports the failing saves
    and saves once it is there."""
    table = getattr(cfg, "table", None)
    if table is None or not table.persist or not getattr(cfg, "table_on", False):
        return []
    path = Path(table.persist)
    if path.is_dir():
        return [f"table.persist: {str(path)!r} is a directory, not a file"]
    if path.exists() and not os.access(path, os.R_OK):
        return [f"table.persist: {str(path)!r} cannot be read"]
    return []


CHECKS = (tls_files, client_tls_files, web_files, listen_hosts, distinct_ports, table_file)


def _tls_served(cfg) -> bool:
    """Master mode serves TLS on the table's server only, while the table is on."""
    return not isinstance(cfg, MasterConfig) or cfg.table.enabled


def _listeners(cfg) -> list[tuple[str, str | None, int]]:
    """(key label, host or None for every address, port) of each listener the start opens."""
    bind = getattr(cfg, "bind", None)
    found: list[tuple[str, str | None, int]] = []
    master = isinstance(cfg, MasterConfig)
    if master:
        if cfg.table.enabled:
            found.append(("table.port", bind, cfg.table.port))
    elif cfg.mdbport:
        found.append(("net.mdbport", bind, cfg.mdbport))
    if cfg.tls.enabled and _tls_served(cfg):
        found.append(("tls.port", bind, cfg.tls.port))
    rtu_port = getattr(cfg, "rtu_port", 0)
    if rtu_port:
        if master:      # the TCP face's own plain port, beside the table's
            found.append(("net.mdbport", bind, cfg.mdbport))
        found.append(("net.rtu-port", bind, rtu_port))
    transparent = getattr(cfg, "transparent", None)
    if transparent is not None and transparent.raw_port is not None:
        found.append(("transparent.raw-port", bind, transparent.raw_port))
    for label, address in (("web.listen", cfg.web.listen), ("general.metrics", cfg.metrics)):
        if address:
            host, port = _host_port(address)
            found.append((label, host, port))
    return found


def _host_port(address: str) -> tuple[str | None, int]:
    """'ADDR:PORT', '[IPV6]:PORT' or ':PORT', already checked by the option."""
    host, _, port = address.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    return host or None, int(port)


def _overlap(a: str | None, b: str | None) -> bool:
    """Two listening hosts take a common address: one is every address, or they are the
    same (an unspecified address, 0.0.0.0 or ::, is every address)."""
    if a is None or b is None or a == b:
        return True
    return _unspecified(a) or _unspecified(b)


def _unspecified(host: str) -> bool:
    try:
        return ipaddress.ip_address(host.split("%", 1)[0]).is_unspecified
    except ValueError:
        return False


def _resolves(host: str) -> bool:
    try:
        socket.getaddrinfo(host, None, socket.AF_UNSPEC, socket.SOCK_STREAM, 0,
                           socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError):
        return False
    return True
