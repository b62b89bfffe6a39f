"""Which servers a pool reaches over TLS, and with what: the one choice every owner of an
UpstreamPool makes (a serial face, the TCP face's server threads).

A server is reached over Modbus/TCP Security when a route says so: a `tls` slaveid range
(implicit routes, dialled on `[tls] server-port`, their plain neighbours on mdbport), or a
`[[route]]` with `tls = true` (dialled on the route's own port).  Either way mbgw presents
`[tls] client-cert` and checks the server against `server-ca` or the route's pinned
fingerprint.
"""
import ssl

from mbgw.config.lines import RouteConfig
from mbgw.config.model import UpstreamTlsConfig
from mbgw.net.tls import client_context
from mbgw.upstream.pool import UpstreamPool


def routes_tls(routes, port: int) -> tuple[frozenset[str], dict[str, bytes]]:
    """The hosts the routes reach over TLS on port, and their pinned fingerprints."""
    found: list[RouteConfig] = [r for r in routes if r.tls and r.server is not None
                                and r.server[1] == port]
    return (frozenset(r.server[0] for r in found if r.server is not None),
            {r.server[0]: r.fingerprint for r in found
             if r.server is not None and r.fingerprint is not None})


class ClientTls:
    """The client context of `[tls]`'s client files, made when first needed and again when
    they change (a renewed file is a change); one per thread that owns pools."""

    def __init__(self) -> None:
        self._settings: UpstreamTlsConfig | None = None
        self._context: ssl.SSLContext | None = None

    def reach(self, pool: UpstreamPool, upstream: UpstreamTlsConfig, tls_port: int,
              hosts: frozenset[str], pins: dict[str, bytes]) -> None:
        """pool reaches hosts over TLS on tls_port, the others in plain (none while upstream
        has no client certificate).  Raises ConfigError (the files do not load)."""
        context = None
        if hosts and upstream.enabled:
            if self._context is None or self._settings != upstream:
                self._context = client_context(upstream)
                self._settings = upstream
            context = self._context
        pool.set_tls(context, tls_port, hosts, pins)
