"""Modbus/TCP Security's options ([tls] keys): the TLS listener (on when a certificate is
given) and TLS to remote servers; each file checked when given (start, reload,
check-config)."""
import click

from mbgw.cli.options import convert, stack
from mbgw.config import model
from mbgw.config.schema import TlsOption


def tls_file(check):
    """A callback checking a [tls] file when one is given (start, reload, check-config)."""
    def callback(ctx, param, value):
        if value is not None:
            convert(f"'{param.opts[0]}'", lambda: check(value))
        return value
    return callback


def check_cert(path, option="tls-cert"):
    from mbgw.net.tls import check_certificate
    check_certificate(path, option)


def check_key(path, option="tls-key"):
    from mbgw.net.tls import check_key
    check_key(path, option)


def _check_ca(path, option="tls-ca"):
    from mbgw.net.tls import check_ca
    check_ca(path, option)


def _crl_callback(ctx, param, value):
    """The CRL readable, and signed by a CA of tls-ca (when that option came first; the mode's
    settings check it again)."""
    if value is not None:
        from mbgw.net.tls import check_crl, check_crl_issuer
        convert("'--tls-crl'", lambda: check_crl(value))
        ca = ctx.params.get("tls_ca")
        if ca is not None:
            convert("'--tls-crl'", lambda: check_crl_issuer(value, ca))
    return value


# Modbus/TCP Security ([tls] keys): TLS is on when a certificate is given.
tls_options = stack(
    click.option("--tls-port", cls=TlsOption, key="tls-port", file_key="port",
                 type=click.IntRange(*model.PORT_RANGE),
                 default=model.DEFAULT_TLS_PORT, show_default=True,
                 help="Modbus/TCP Security (TLS) port, with --tls-cert."),
    click.option("--tls-cert", cls=TlsOption, key="cert", metavar="PATH", default=None,
                 callback=tls_file(check_cert),
                 help="Server certificate (PEM): turns TLS on (TLS 1.2/1.3, client "
                      "certificates required) [default: off]."),
    click.option("--tls-key", cls=TlsOption, key="key", metavar="PATH", default=None,
                 callback=tls_file(check_key),
                 help="The server certificate's private key (PEM, unencrypted)."),
    click.option("--tls-ca", cls=TlsOption, key="ca", metavar="PATH", default=None,
                 callback=tls_file(_check_ca),
                 help="CA certificate(s) (PEM) that client certificates must chain to; the "
                      "client's role is its certificate's extension %s." % model.ROLE_OID),
    click.option("--tls-require-role/--no-tls-require-role", cls=TlsOption,
                 key="require-role", default=model.TlsConfig.require_role, show_default=True,
                 help="Refuse every request (exception 0x01) of a TLS client whose "
                      "certificate has no role; the session stays open."),
    click.option("--tls-crl", cls=TlsOption, key="crl", metavar="PATH", default=None,
                 callback=_crl_callback,
                 help="Revoked client certificates (PEM CRL of the CA): a revoked client is "
                      "refused in the handshake; reloaded with SIGHUP [default: none]."),
)


def tls_config(tls_port, tls_cert, tls_key, tls_ca, tls_require_role=True,
               tls_crl=None) -> model.TlsConfig:
    from mbgw.net.tls import check_crl_issuer, file_stamps
    if tls_crl is not None and tls_ca is not None:
        convert("'--tls-crl'", lambda: check_crl_issuer(tls_crl, tls_ca))
    return convert("'--tls-cert'", lambda: model.TlsConfig(
        port=tls_port, cert=tls_cert, key=tls_key, ca=tls_ca, require_role=tls_require_role,
        crl=tls_crl, files=file_stamps(tls_cert, tls_key, tls_ca, tls_crl)))


def _client_file(check, option):
    return tls_file(lambda path: check(path, option))


# TLS to remote servers (master mode's `tls` slaveid ranges, `tls` TCP scenarios): [tls] keys.
upstream_tls_options = stack(
    click.option("--tls-client-cert", cls=TlsOption, key="client-cert", metavar="PATH",
                 default=None, callback=_client_file(check_cert, "tls-client-cert"),
                 help="mbgw's certificate (PEM) for servers reached over TLS (a slaveid range's "
                      "or a TCP scenario's `tls`)."),
    click.option("--tls-client-key", cls=TlsOption, key="client-key", metavar="PATH",
                 default=None, callback=_client_file(check_key, "tls-client-key"),
                 help="The client certificate's private key (PEM, unencrypted)."),
    click.option("--tls-server-ca", cls=TlsOption, key="server-ca", metavar="PATH",
                 default=None, callback=_client_file(_check_ca, "tls-server-ca"),
                 help="CA certificate(s) (PEM) that the servers' certificates must chain to."),
    click.option("--tls-server-port", cls=TlsOption, key="server-port",
                 type=click.IntRange(*model.PORT_RANGE),
                 default=model.DEFAULT_TLS_PORT, show_default=True,
                 help="Master mode: the TLS port of the servers of `tls` slaveid ranges."),
)


def upstream_tls_config(settings: dict) -> model.UpstreamTlsConfig:
    """UpstreamTlsConfig from the click values, taken out of settings."""
    return _upstream_tls_config(**{name: settings.pop(name) for name in (
        "tls_client_cert", "tls_client_key", "tls_server_ca", "tls_server_port")
        if name in settings})


def _upstream_tls_config(tls_client_cert=None, tls_client_key=None, tls_server_ca=None,
                         tls_server_port=model.DEFAULT_TLS_PORT) -> model.UpstreamTlsConfig:
    from mbgw.net.tls import file_stamps
    return convert("'--tls-client-cert'", lambda: model.UpstreamTlsConfig(
        client_cert=tls_client_cert, client_key=tls_client_key, server_ca=tls_server_ca,
        server_port=tls_server_port,
        files=file_stamps(tls_client_cert, tls_client_key, tls_server_ca)))
