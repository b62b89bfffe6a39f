"""Northbound MQTT's metric families, from its status (mbgw.northbound.counters)."""
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily


def mqtt_families(status: dict):
    """Northbound MQTT: the connection and its counts."""
    yield GaugeMetricFamily("mbgw_mqtt_connected", "1 while the MQTT broker's session is up.",
                            value=1 if status["connected"] else 0)
    for name, key, help_text in (
            ("mbgw_mqtt_messages_sent_total", "messages_sent", "MQTT messages published."),
            ("mbgw_mqtt_messages_dropped_total", "messages_dropped",
             "Values a slow MQTT broker could not take (a later message carried the latest)."),
            ("mbgw_mqtt_commands_refused_total", "commands_refused",
             "Writes from MQTT refused (no role, the firewall, a value the type cannot "
             "carry)."),
            ("mbgw_mqtt_connects_total", "connects", "MQTT sessions opened.")):
        yield CounterMetricFamily(name, help_text, value=status[key])
