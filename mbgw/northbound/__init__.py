"""Northbound MQTT: the exchange table's data that read scenarios fill, each device's health
and each line's state, published to a broker as a Sparkplug B 3.0 edge node or plain JSON,
and the writes that come back, on the daemon's asyncio loop (paho's network loop in paho's
own thread), never on a line thread's path.

May import net, ops, table, scenarios, firewall, config and protocol, besides errors and
audit.  See docs/architecture.md#details-northbound-mqtt.
"""
