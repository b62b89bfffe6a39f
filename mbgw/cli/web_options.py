"""The web console's options ([web] keys; on with --web, the password hashes file keys
only) and the WebConfig they build."""
import click

from mbgw.cli.options import convert, parser, stack
from mbgw.cli.tls_options import check_cert, check_key, tls_file
from mbgw.config import model
from mbgw.config.schema import WebOption


def _parse_listen(value):
    if value is not None:
        from mbgw.net.address import parse_host_port
        parse_host_port(value, example="127.0.0.1:8080")
    return value


def _password_hash(label: str):
    def parse(value):
        if value is not None:
            from mbgw.web.passwords import check_hash
            check_hash(value, label)
        return value
    return parse


_HTTPS_ONLY = "mbgw.web-https-only"     # ctx.meta: https-only seen before --web-cert


def _needs_web_cert(ctx, param, value):
    """https-only without a certificate is refused in the options' callbacks, so at start,
    reload and check-config alike; click may process either option first."""
    if value:
        if "web_cert" not in ctx.params:
            ctx.meta[(_HTTPS_ONLY, id(ctx))] = True
        elif ctx.params["web_cert"] is None:
            _https_only_refused()
    return value


def _web_cert(ctx, param, value):
    value = tls_file(check_cert)(ctx, param, value)
    if value is None and ctx.meta.pop((_HTTPS_ONLY, id(ctx)), False):
        _https_only_refused()
    return value


def _https_only_refused():
    raise click.BadParameter("needs HTTPS: give --web-cert and --web-key (web.cert and "
                             "web.key)", param_hint="'--web-https-only'")


# The web console ([web] keys): on with --web; the password hashes are file keys only.
web_options = stack(
    click.option("--web", "web_listen", cls=WebOption, key="web", file_key="listen",
                 metavar="ADDR:PORT", default=None, callback=parser(_parse_listen),
                 help="Serve the web console on http(s)://ADDR:PORT/ ([IPV6]:PORT; :PORT for "
                      "every address); needs an admin password (mbgw config password admin) "
                      "[default: off]."),
    click.option("--web-cert", cls=WebOption, key="web-cert", file_key="cert", metavar="PATH",
                 default=None, callback=_web_cert,
                 help="The web console's certificate (PEM): HTTPS, with --web-key."),
    click.option("--web-key", cls=WebOption, key="web-key", file_key="key", metavar="PATH",
                 default=None, callback=tls_file(check_key),
                 help="The web console certificate's private key (PEM, unencrypted)."),
    click.option("--web-admin-password", cls=WebOption, key="admin-password", secret=True,
                 hidden=True, default=None,
                 callback=parser(_password_hash("web.admin-password")),
                 help="The admin's password hash (set by mbgw config password admin)."),
    click.option("--web-user-password", cls=WebOption, key="user-password", secret=True,
                 hidden=True, default=None,
                 callback=parser(_password_hash("web.user-password")),
                 help="The user's password hash (set by mbgw config password user)."),
    click.option("--web-https-only/--no-web-https-only", cls=WebOption, key="web-https-only",
                 file_key="https-only", default=model.WebConfig.https_only, show_default=True,
                 callback=_needs_web_cert,
                 help="With --web-cert: a plain HTTP request on the console's port is "
                      "redirected to HTTPS, and every answer sets Strict-Transport-Security."),
)


WEB_PARAMS = ("web_listen", "web_cert", "web_key", "web_admin_password", "web_user_password",
              "web_https_only")


def web_config(options: dict) -> model.WebConfig:
    """WebConfig from the click values; takes them out of `options` (the mode's own
    function does not know them)."""
    web = {name: options.pop(name, None) for name in WEB_PARAMS}
    return convert("'--web'", lambda: model.WebConfig(
        listen=web["web_listen"], cert=web["web_cert"], key=web["web_key"],
        admin_password=web["web_admin_password"], user_password=web["web_user_password"],
        https_only=bool(web["web_https_only"])))
