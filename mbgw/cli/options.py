"""What the mode commands share: the serial line's options, the operator's tools, turning a
configuration error into a usage error, and the one way a command fails."""
import os
from collections.abc import Callable

import click

from mbgw.config import model
from mbgw.config.firewall import FirewallConfig
from mbgw.config.number_list import parse_number_list
from mbgw.config.schema import SerialOption, TableOption, TlsOption, WebOption
from mbgw.errors import ConfigError


class Failure(click.ClickException):
    """Printed as "mbgw: ..." lines on stderr; exit status 1, or `exit_code`."""

    def __init__(self, message: str, exit_code: int = 1) -> None:
        super().__init__(message)
        self.exit_code = exit_code      # type: ignore[misc]  # click's is a ClassVar

    def show(self, file=None) -> None:
        for line in self.format_message().splitlines():
            click.echo(f"mbgw: {line}", file=file, err=file is None)


EX_CONFIG = 78                     # sysexits.h; the units do not restart on it
META_FILE = "mbgw.config_file"     # ctx.meta: the file the running mode command took values from


class ModeCommand(click.Command):
    """A mode command (slave, master, transparent): make_config(**params) builds the
    settings its daemon starts with (mbgw.cli.checks).  A value from its configuration file
    that a check of the options refuses (the CRL and the CA, checked together) is the file's
    problem: EX_CONFIG, naming the file and the key, not a usage error."""
    make_config: Callable | None = None
    # (the file in use, its values by parameter name) for -h, or None (mbgw.cli.config_option)
    file_values: Callable[[click.Context], tuple[object, dict] | None] | None = None

    def format_options(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The built-in defaults (not the file's, which click's default_map would show), and
        beside each the value the file in use sets instead."""
        file_values = getattr(type(self), "file_values", None)
        found = file_values(ctx) if file_values is not None else None
        saved, ctx.default_map = ctx.default_map, None
        try:
            rows = []
            for param in self.get_params(ctx):
                record = param.get_help_record(ctx)
                if record is None or isinstance(param, click.Argument):
                    continue
                if found is not None and param.name in found[1]:
                    shown = _shown(found[1][param.name])
                    if shown != _shown(param.default):
                        record = (record[0], f"{record[1]}  [{found[0]} sets {shown}]")
                rows.append(record)
        finally:
            ctx.default_map = saved
        if rows:
            with formatter.section("Options"):
                formatter.write_dl(rows)

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, args)
        except click.BadParameter as err:
            path, param, root = ctx.meta.get(META_FILE), err.param, ctx.find_root().command
            if path is None or param is None or param.name is None or \
                    ctx.get_parameter_source(param.name) \
                    is not click.core.ParameterSource.DEFAULT_MAP:
                raise
            from mbgw.config.schema import Schema
            key = Schema(root).key_of_param(param) if isinstance(root, click.Group) else None
            label = key.label if key is not None else param.name
            raise Failure(f"{path}: {label}: {err.message}", EX_CONFIG) from None


def _shown(value) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, list | tuple):
        return " ".join(map(_shown, value)) or "(empty)"
    return str(value)


LOG_LEVELS = click.Choice(["debug", "info", "warning", "error"], case_sensitive=False)


def convert(param_name: str | None, build):
    """Run a config constructor, turning ConfigError into a usage error (exit 2) naming the
    option: the error's key when it carries one (the message then without the key, which
    the hint says), else param_name (None: no option in particular)."""
    try:
        return build()
    except ConfigError as err:
        if err.key is None:
            raise click.BadParameter(str(err), param_hint=param_name) from None
        message = str(err)
        for said in (f"{err.key}: ", f"{err.key} "):
            message = message.removeprefix(said)
        raise click.BadParameter(message, param_hint=f"'--{err.key}'") from None


def parser(parse):
    def callback(ctx, param, value):
        return convert(f"'{param.opts[0]}'", lambda: parse(value))
    return callback


def parse_authip(values) -> tuple:
    """--authip: IP addresses (an IPv4-mapped IPv6 one as its IPv4 address)."""
    return tuple(str(model.parse_ip("authip", v)) for v in values)


def parse_bind(value):
    """--bind: an IP address (the listeners bind it as given, scope id included)."""
    if value is not None:
        try:
            model.parse_ip("bind", value)
        except ConfigError:
            raise ConfigError(f"{value!r} is not an IP address") from None
    return value


def _parse_metrics(value):
    if value is not None:
        from mbgw.net.address import parse_host_port
        parse_host_port(value, "metrics")
    return value


def _check_device(path):
    """A path that can never be a serial device is refused (start, reload, check-config)."""
    from mbgw.config.device import device_problem
    if path is not None and (problem := device_problem(path)):
        raise ConfigError(problem)
    return path


def stack(*decorators):
    def apply(function):
        for decorator in reversed(decorators):
            function = decorator(function)
        return function
    return apply


serial_options = stack(
    click.option("--device", cls=SerialOption, required=True, metavar="PATH",
                 callback=parser(_check_device),
                 help="Serial device, e.g. /dev/ttyUSB0; one that is not there yet is "
                      "waited for."),
    click.option("--protocol", cls=SerialOption, type=click.Choice(model.PROTOCOLS),
                 default=model.SerialConfig.protocol, show_default=True,
                 help="Modbus framing on the serial line."),
    click.option("--baudrate", cls=SerialOption, type=click.IntRange(*model.BAUDRATE_RANGE),
                 default=model.SerialConfig.baudrate, show_default=True,
                 help="Line speed in bit/s, any rate from %d to %d." % model.BAUDRATE_RANGE),
    click.option("--format", "line_format", cls=SerialOption, default=str(model.LineFormat()),
                 show_default=True,
                 callback=parser(model.LineFormat.parse), metavar="NPS",
                 help="Data bits (7|8), parity (n|e|o|m|s: none, even, odd, mark, space), "
                      "stop bits (1|2)."),
    click.option("--interface", cls=SerialOption, default=str(model.Interface()),
                 show_default=True,
                 callback=parser(model.Interface.parse), metavar="KIND",
                 help="rs232; 'rs422 master' (or rs422), 'rs422 slave' (the transmitter on "
                      "only while sending, for multidrop); 'rs485 noecho' (or rs485) or "
                      "'rs485 echo' (the transceiver hears its own frames; they are dropped). "
                      "4wires is rs422, 2wires rs485."),
    click.option("--rtsdelays", cls=SerialOption,
                 type=(click.IntRange(*model.RTSDELAY_RANGE),
                       click.IntRange(*model.RTSDELAY_RANGE)),
                 default=model.SerialConfig.rtsdelays, show_default=True, metavar="BEFORE AFTER",
                 help="RS-485, an RS-422 slave or --rts modem: ms between raising RTS and "
                      "the first byte, and between the last byte and dropping RTS, 0..255."),
    click.option("--dtr", cls=SerialOption, type=click.Choice(model.DTR_MODES),
                 default=model.SerialConfig.dtr, show_default=True,
                 help="RS-232 DTR held high or low (a modem's on-line line)."),
    click.option("--rts", cls=SerialOption, type=click.Choice(model.RTS_MODES),
                 default=model.SerialConfig.rts, show_default=True,
                 help="RS-232 RTS: held high or low; flow: RTS/CTS flow control (with --cts "
                      "flow); modem: raised for each frame with --rtsdelays around it, a "
                      "radio modem's push-to-talk."),
    click.option("--cts", cls=SerialOption, type=click.Choice(model.CTS_MODES),
                 default=model.SerialConfig.cts, show_default=True,
                 help="RS-232 CTS: ignored, or flow: send only while CTS is up (with --rts "
                      "flow)."),
    click.option("--xonxoff", cls=SerialOption, type=click.Choice(model.XONXOFF_MODES),
                 default=model.SerialConfig.xonxoff, show_default=True,
                 help="XON/XOFF software flow control on the line: use or ignore."),
    click.option("--stout", cls=SerialOption, type=click.IntRange(*model.STOUT_RANGE),
                 default=model.DEFAULT_STOUT_MS, show_default=True, metavar="MS",
                 help="Time from the end of a request to the end of its answer, 1..65535 ms."),
    click.option("--silence", cls=SerialOption, type=click.IntRange(*model.SILENCE_RANGE),
                 default=model.SerialConfig.silence_ms, show_default=True,
                 metavar="MS",
                 help="RTU end-of-frame silence in ms, 0..65535 (0: the standard 3.5 "
                      "characters, 1.75 ms above 19200 bit/s); shorter gaps stay inside "
                      "a frame."),
    click.option("--ascii-timeout", cls=SerialOption,
                 type=click.IntRange(*model.ASCII_TIMEOUT_RANGE),
                 default=model.DEFAULT_ASCII_TIMEOUT_MS, show_default=True, metavar="MS",
                 help="ASCII: longest pause between two characters of a frame, 1..65535 ms."),
    click.option("--nocheck", cls=SerialOption, is_flag=True, default=model.SerialConfig.nocheck,
                 show_default=True,
                 help="Debugging only: forward serial replies unchecked (no CRC/LRC, "
                      "address or length control), as received until end of frame.  "
                      "[default: off]"),
)


# Demotion of silent serial addresses, the same rule in both modes ([serial] keys).
demotion_options = stack(
    click.option("--down-after", cls=SerialOption, type=click.IntRange(*model.DOWN_AFTER_RANGE),
                 default=model.DEFAULT_DOWN_AFTER, show_default=True, metavar="N",
                 help="A serial address is down after N requests in a row without a valid "
                      "reply; its requests are then refused at once (0x0B with --exception) "
                      "but for a probe per --probe-interval, until it answers.  0: never "
                      "down.  %d..%d." % model.DOWN_AFTER_RANGE),
    click.option("--probe-interval", cls=SerialOption,
                 type=click.IntRange(*model.PROBE_INTERVAL_RANGE),
                 default=model.DEFAULT_PROBE_INTERVAL_MS, show_default=True, metavar="MS",
                 help="While an address is down, one request per interval goes to it as a "
                      "probe; the interval doubles while the probes fail, up to %d ms.  "
                      "%d..%d ms." % (model.PROBE_BACKOFF_MAX_MS,
                                      *model.PROBE_INTERVAL_RANGE)),
)


def demotion(down_after: int, probe_interval: int) -> model.Demotion:
    return convert("'--down-after'", lambda: model.Demotion(down_after, probe_interval))


# The exchange table ([table] keys): --table first, then the mode's own options, then these.
table_switch = click.option(
    "--table/--no-table", "table_enabled", cls=TableOption, key="enabled",
    default=model.TableConfig.enabled, show_default=True,
    help="Serve the exchange table: 65,536 registers of local data that Modbus TCP clients "
         "and the serial side read and write (mbgw.toml(5), [table]).  Slave mode: TCP "
         "units --table-units reach it (every unit with --no-direct); master mode: the "
         "serial address --table-address, and TCP clients on --table-port.")


def _parse_functions(value, option: str = "table-functions") -> tuple[int, ...]:
    functions = parse_number_list(option, value, 1, 255)
    others = [str(f) for f in functions if f not in model.TABLE_FUNCTIONS]
    if others:
        raise ConfigError(f"{option} {value!r}: {', '.join(others)}: the table "
                          f"answers only {', '.join(map(str, model.TABLE_FUNCTIONS))}")
    return functions


def parse_serial_functions(value) -> tuple[int, ...] | None:
    return None if value is None else _parse_functions(value, "table-serial-functions")


def _parse_persist(value):
    if value is not None and value != PERSIST_OFF:
        model.check_persist_path(str(value))
    return value


table_options = stack(
    click.option("--table-functions", cls=TableOption, key="functions",
                 default=",".join(map(str, model.TABLE_FUNCTIONS)), show_default=True,
                 callback=parser(_parse_functions), metavar="LIST",
                 help="Function codes the table answers, of %s (e.g. 3,4,6,16); any other "
                      "is exception 0x01." % ",".join(map(str, model.TABLE_FUNCTIONS))),
    click.option("--table-persist", cls=TableOption, key="persist", metavar="PATH",
                 default=model.TableConfig.persist, callback=parser(_parse_persist),
                 help="Keep the outputs and the free zone (0x0800-0x7FFF) in this file "
                      "across restarts, written atomically; a regular file in the state "
                      "directory ($STATE_DIRECTORY, else %s); off: not kept [default: "
                      "$STATE_DIRECTORY/table under the units, else not kept]."
                      % model.DEFAULT_STATE_DIRECTORY),
    click.option("--table-persist-interval", cls=TableOption, key="persist-interval",
                 type=click.IntRange(*model.PERSIST_INTERVAL_RANGE),
                 default=model.DEFAULT_PERSIST_INTERVAL_S, show_default=True, metavar="S",
                 help="With --table-persist: save changes at most every S seconds "
                      "(%d..%d), and at stop." % model.PERSIST_INTERVAL_RANGE),
)


PERSIST_OFF = "off"
PERSIST_FILE = "table"       # the default file's name in the state directory


def persist_path(value: str | None) -> str | None:
    """The table's file: the one given; none for "off"; when none is given, `table` in the
    state directory systemd gives the units (StateDirectory=, $STATE_DIRECTORY), else none
    (mbgw run by hand does not write somewhere it was not told to)."""
    if value is not None:
        return None if value == PERSIST_OFF else value
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return os.path.join(state, PERSIST_FILE) if state else None


def table_config(**settings) -> model.TableConfig:
    """TableConfig from the click values (table_enabled, table_functions, ...)."""
    fields = {"enabled": "table_enabled", "direct": "table_direct", "units": "table_units",
              "functions": "table_functions", "serial_functions": "table_serial_functions",
              "address": "table_address",
              "port": "table_port", "persist_interval_s": "table_persist_interval",
              "max_connections": "table_max_connections"}
    return convert("'--table'", lambda: model.TableConfig(
        persist=persist_path(settings.get("table_persist")),
        **{f: settings[o] for f, o in fields.items() if settings.get(o) is not None}))


def _tls_file(check):
    """A callback checking a [tls] file when one is given (start, reload, check-config)."""
    def callback(ctx, param, value):
        if value is not None:
            convert(f"'{param.opts[0]}'", lambda: check(value))
        return value
    return callback


def _check_cert(path, option="tls-cert"):
    from mbgw.net.tls import check_certificate
    check_certificate(path, option)


def _check_key(path, option="tls-key"):
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
                 callback=_tls_file(_check_cert),
                 help="Server certificate (PEM): turns TLS on (TLS 1.2/1.3, client "
                      "certificates required) [default: off]."),
    click.option("--tls-key", cls=TlsOption, key="key", metavar="PATH", default=None,
                 callback=_tls_file(_check_key),
                 help="The server certificate's private key (PEM, unencrypted)."),
    click.option("--tls-ca", cls=TlsOption, key="ca", metavar="PATH", default=None,
                 callback=_tls_file(_check_ca),
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
    return _tls_file(lambda path: check(path, option))


# TLS to remote servers (master mode's `tls` slaveid ranges, `tls` TCP scenarios): [tls] keys.
upstream_tls_options = stack(
    click.option("--tls-client-cert", cls=TlsOption, key="client-cert", metavar="PATH",
                 default=None, callback=_client_file(_check_cert, "tls-client-cert"),
                 help="mbgw's certificate (PEM) for servers reached over TLS (a slaveid range's "
                      "or a TCP scenario's `tls`)."),
    click.option("--tls-client-key", cls=TlsOption, key="client-key", metavar="PATH",
                 default=None, callback=_client_file(_check_key, "tls-client-key"),
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


# The operator's tools, the same in both modes: control socket, metrics, log level.
class _FirewallRules(click.ParamType):
    """The firewall comes from the configuration file only (mbgw.config.firewall): its
    checked rules reach the command through click's default_map, never as text."""
    name = "rules"

    def convert(self, value, param, ctx):
        if isinstance(value, FirewallConfig):
            return value
        self.fail("firewall rules are set in the configuration file's [[rule]] tables "
                  "(mbgw.toml(5))", param, ctx)


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
    value = _tls_file(_check_cert)(ctx, param, value)
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
                 default=None, callback=_tls_file(_check_key),
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


daemon_options = stack(
    click.option("--request-timeout", type=click.IntRange(*model.REQUEST_TIMEOUT_RANGE),
                 default=model.DEFAULT_REQUEST_TIMEOUT_MS, show_default=True, metavar="MS",
                 help="A request begun (a Modbus request's first byte, a TLS handshake, an "
                      "HTTP request) must be whole within MS, or its connection is closed; "
                      "a connection that has sent no whole request is the first a newcomer "
                      "replaces.  %d..%d ms." % model.REQUEST_TIMEOUT_RANGE),
    click.option("--location", default=model.DEFAULT_LOCATION, show_default=True,
                 metavar="TEXT", callback=parser(model.parse_location),
                 help="Where the gateway is, up to %d ASCII characters: shown by mbgw status, "
                      "the web console and the table's configuration zone." % model.LOCATION_MAX),
    click.option("--control", metavar="PATH", default=None,
                 help="Control socket for mbgw status/trace [default: "
                      "$RUNTIME_DIRECTORY/mbgw.sock or /run/mbgw/mbgw.sock]."),
    click.option("--metrics", metavar="ADDR:PORT", default=None,
                 callback=parser(_parse_metrics),
                 help="Serve Prometheus metrics on http://ADDR:PORT/metrics ([IPV6]:PORT; "
                      ":PORT for every address) [default: off]."),
    click.option("--log-level", type=LOG_LEVELS, default="info", show_default=True),
    click.option("--log-format", type=click.Choice(["text", "json"]), default="text",
                 show_default=True,
                 help="text: lines for people (under systemd: journal records with the "
                      "audit events' MESSAGE_ID and fields); json: one JSON object per line on "
                      "stderr with the same fields."),
    click.option("--firewall", type=_FirewallRules(), default=None, hidden=True,
                 help="The configuration file's [[rule]] tables and [firewall] group."),
    web_options,
)


# Slave and master modes' (transparent mode's is its own, [transparent] silence).
interframe_option = click.option(
    "--interframe-silence", cls=SerialOption, type=click.IntRange(*model.INTERFRAME_SILENCE_RANGE),
    default=model.SerialConfig.interframe_ms, show_default=True, metavar="MS",
    help="VPGate's interframe silence: ms, beyond t3.5, that the line stays quiet after a "
         "frame before mbgw sends (slave mode: the next request after a reply; master mode: "
         "its answer after a request), 0..65535.")


def serial_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout,
                   silence, ascii_timeout, nocheck, dtr="high", rts="high", cts="ignore",
                   xonxoff="ignore", interframe_silence=0) -> model.SerialConfig:
    try:
        return model.SerialConfig(
            device=device, protocol=protocol, baudrate=baudrate, format=line_format,
            interface=interface, rtsdelays=tuple(rtsdelays), stout_ms=stout,
            silence_ms=silence, ascii_timeout_ms=ascii_timeout, nocheck=nocheck, dtr=dtr,
            rts=rts, cts=cts, xonxoff=xonxoff, interframe_ms=interframe_silence)
    except ConfigError as err:
        option = str(err).split(" ", 1)[0]     # the message opens with the setting's name
        raise click.BadParameter(str(err), param_hint=f"'--{option}'") from None
