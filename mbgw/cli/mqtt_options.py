"""Northbound MQTT's options ([mqtt] keys; on with --mqtt-broker) and the MqttConfig they
build."""
import click

from mbgw.cli.options import convert, parser, stack
from mbgw.cli.tls_options import check_cert, check_key, tls_file
from mbgw.config import mqtt
from mbgw.config.schema import MqttOption


def _check_ca(path, option="mqtt-ca"):
    from mbgw.net.tls import check_ca
    check_ca(path, option)


def _broker(value):
    if value is not None:
        mqtt.broker_address(value)
    return value


mqtt_options = stack(
    click.option("--mqtt-broker", cls=MqttOption, key="mqtt-broker", file_key="broker",
                 metavar="URL", default=None, callback=parser(_broker),
                 help="Publish the scenarios' data to this MQTT broker: mqtt://HOST[:PORT] "
                      "(1883) or mqtts://HOST[:PORT] (8883, TLS, the broker's certificate "
                      "checked against HOST) [default: off]."),
    click.option("--mqtt-profile", cls=MqttOption, key="mqtt-profile", file_key="profile",
                 type=click.Choice(mqtt.PROFILES), default=mqtt.DEFAULT_PROFILE,
                 show_default=True,
                 help="sparkplug: a Sparkplug B 3.0 edge node; json: GROUP/NODE/DEVICE/METRIC "
                      "topics with JSON values and Home Assistant discovery."),
    click.option("--mqtt-group", cls=MqttOption, key="mqtt-group", file_key="group",
                 metavar="ID", default=mqtt.DEFAULT_GROUP, show_default=True,
                 help="The Sparkplug group id (json: the topics' first level)."),
    click.option("--mqtt-node", cls=MqttOption, key="mqtt-node", file_key="node",
                 metavar="ID", default=None,
                 help="The edge node id [default: the short host name; HOST-NAME for the "
                      "instance mbgw@NAME]."),
    click.option("--mqtt-role", cls=MqttOption, key="mqtt-role", file_key="role",
                 metavar="ROLE", default=None,
                 help="The firewall role of writes from MQTT (listener mqtt, unit = the serial "
                      "address) [default: none: every write refused]."),
    click.option("--mqtt-primary-host", cls=MqttOption, key="mqtt-primary-host",
                 file_key="primary-host", metavar="ID", default=None,
                 help="Sparkplug primary host application id: births wait for its STATE "
                      "online [default: none]."),
    click.option("--mqtt-cert", cls=MqttOption, key="mqtt-cert", file_key="cert",
                 metavar="PATH", default=None, callback=tls_file(
                     lambda p: check_cert(p, "mqtt-cert")),
                 help="Client certificate (PEM) for the broker [default: [tls] client-cert]."),
    click.option("--mqtt-key", cls=MqttOption, key="mqtt-key", file_key="key",
                 metavar="PATH", default=None, callback=tls_file(
                     lambda p: check_key(p, "mqtt-key")),
                 help="The client certificate's private key (PEM) [default: [tls] "
                      "client-key]."),
    click.option("--mqtt-ca", cls=MqttOption, key="mqtt-ca", file_key="ca",
                 metavar="PATH", default=None, callback=tls_file(_check_ca),
                 help="CA certificate(s) the broker's certificate chains to [default: [tls] "
                      "server-ca, else the system's]."),
    click.option("--mqtt-stale-after", cls=MqttOption, key="mqtt-stale-after",
                 file_key="stale-after", metavar="MS",
                 type=click.IntRange(*mqtt.STALE_AFTER_RANGE), default=0, show_default=True,
                 help="A metric whose scenario has not read it for this long is published as "
                      "stale (a scenario's own stale-after first); 0: off."),
)


MQTT_PARAMS = ("mqtt_broker", "mqtt_profile", "mqtt_group", "mqtt_node", "mqtt_role",
               "mqtt_primary_host", "mqtt_cert", "mqtt_key", "mqtt_ca", "mqtt_stale_after")


def mqtt_config(options: dict) -> mqtt.MqttConfig:
    """MqttConfig from the click values; takes them out of `options` (the mode's own function
    does not know them)."""
    given = {name: options.pop(name, None) for name in MQTT_PARAMS}
    return convert("'--mqtt-broker'", lambda: mqtt.MqttConfig(
        broker=given["mqtt_broker"], profile=given["mqtt_profile"] or mqtt.DEFAULT_PROFILE,
        group=given["mqtt_group"] or mqtt.DEFAULT_GROUP, node=given["mqtt_node"],
        role=given["mqtt_role"], primary_host=given["mqtt_primary_host"],
        cert=given["mqtt_cert"], key=given["mqtt_key"], ca=given["mqtt_ca"],
        stale_after_ms=given["mqtt_stale_after"] or 0))
