"""The options every mode's daemon shares, the operator's tools: request timeout,
location, control socket, metrics, logging, the firewall (from the file only) and the web
console."""
import click

from mbgw.cli.mqtt_options import mqtt_options
from mbgw.cli.options import parser, stack
from mbgw.cli.web_options import web_options
from mbgw.config import model
from mbgw.config.firewall import FirewallConfig

LOG_LEVELS = click.Choice(["debug", "info", "warning", "error"], case_sensitive=False)


def _parse_metrics(value):
    if value is not None:
        from mbgw.net.address import parse_host_port
        parse_host_port(value, "metrics")
    return value


class _FirewallRules(click.ParamType):
    """The firewall comes from the configuration file only (mbgw.config.firewall): its
    checked rules reach the command through click's default_map, never as text."""
    name = "rules"

    def convert(self, value, param, ctx):
        if isinstance(value, FirewallConfig):
            return value
        self.fail("firewall rules are set in the configuration file's [[rule]] tables "
                  "(mbgw.toml(5))", param, ctx)


gateway_unit_option = click.option(
    "--gateway-unit", type=click.IntRange(*model.GATEWAY_UNIT_RANGE), default=0,
    show_default=True, metavar="UNIT",
    help="A unit id (TCP faces) and serial address (serial faces) that the gateway answers "
         "itself, with its identity functions only (FC 8 diagnostics, FC 17 report server "
         "id, FC 43/14 read device identification; any other function is exception 0x01).  "
         "Outside every route and the table's units.  0: off.")

scenario_tcpto_option = click.option(
    "--tcpto", type=click.IntRange(*model.TCPTO_RANGE), default=model.DEFAULT_TCPTO_MS,
    show_default=True, metavar="MS",
    help="TCP scenarios: the time for a transaction with a server, connecting included.")

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
    click.option("--log-level", type=LOG_LEVELS, default="info", show_default=True,
                 help="The least severe messages logged: debug adds every transaction."),
    click.option("--log-format", type=click.Choice(["text", "json"]), default="text",
                 show_default=True,
                 help="text: lines for people (under systemd: journal records with the "
                      "audit events' MESSAGE_ID and fields); json: one JSON object per line on "
                      "stderr with the same fields."),
    click.option("--firewall", type=_FirewallRules(), default=None, hidden=True,
                 help="The configuration file's [[rule]] tables and [firewall] group."),
    web_options,
    mqtt_options,
)
