"""The remote Modbus TCP servers' metric families (slave mode's `server =` routes), labelled
by HOST:PORT, from the status's "servers" rows (mbgw.slave.servers)."""
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

_SERVER_HELP = {
    "requests": "Requests routed to the remote Modbus TCP server (broadcasts included).",
    "replies": "Replies from the server (exception replies included).",
    "device_exceptions": "Exception replies the server sent.",
    "gateway_exceptions": "Exception replies the gateway sent for the server (0x0A: not "
                          "reached, 0x0B: no reply within tcpto).",
    "timeouts": "Requests the server did not answer within tcpto (or answered wrongly).",
    "unreachable": "Requests whose server could not be reached (connection failed).",
    "broadcasts": "Broadcasts (unit 0) sent to the server.",
    "late_replies": "Server replies that came after tcpto, dropped by transaction id.",
    "wrong_unit": "Server replies with another unit id than the one sent.",
    "wrong_function": "Server replies with another function, size or echo than the request "
                      "asked.",
    "connections_opened": "Connections opened to the server (reconnects included).",
    "connections_evicted": "Connections to the server closed to make room for another.",
    "connections_lost": "Connections to the server closed by the server or broken.",
    "connections_bad_header": "Connections to the server closed for a bad MBAP header.",
}


def server_families(rows: list[dict]):
    """The remote servers' families (slave mode's `server =` routes), labelled by HOST:PORT,
    from the status's "servers" rows."""
    if not rows:
        return
    for name in rows[0]["counters"]:
        family = CounterMetricFamily(f"mbgw_server_{name}", _SERVER_HELP.get(name) or
                                     name.replace("_", " ") + ".", labels=["server"])
        for row in rows:
            family.add_metric([row["server"]], row["counters"][name])
        yield family
    connections = GaugeMetricFamily("mbgw_server_connections",
                                    "Connections open to the server.", labels=["server"])
    for row in rows:
        connections.add_metric([row["server"]], len(row["connections"]))
    yield connections

