"""The Modbus TCP face's metric families by listener (the status's "faces"), and the
firewall's refusals by rule (its status dict, mbgw.firewall)."""
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

_FACE_HELP = {
    "requests": "Requests received on the Modbus TCP face, by listener (plain, tls, udp, "
                "rtu).",
    "refused": "Connections and requests refused by authip or the firewall, by listener "
               "(a refused UDP source gets no datagram).",
    "retransmissions": "UDP requests received again within stout, answered from memory "
                       "without reaching the target.",
    "bad_frames": "RTU-over-TCP requests dropped for a bad CRC, datagrams on udp-port that "
                  "are no MBAP frame.",
    "dropped": "UDP requests dropped unanswered: their source had 16 requests in the gateway "
               "already (a TCP client is not read meanwhile).",
}


def face_families(faces: dict[str, dict[str, int]]):
    """The Modbus TCP face's families, labelled by listener, from the status's "faces"."""
    for name, help_text in _FACE_HELP.items():
        family = CounterMetricFamily(f"mbgw_face_{name}", help_text, labels=["listener"])
        for listener, figures in faces.items():
            family.add_metric([listener], figures[name])
        yield family
    clients = GaugeMetricFamily("mbgw_face_clients", "Clients of the Modbus TCP face now, by "
                                "listener (udp: the sources it remembers).",
                                labels=["listener"])
    for listener, figures in faces.items():
        clients.add_metric([listener], figures["clients"])
    yield clients



def firewall_family(status: dict) -> CounterMetricFamily:
    """Requests the firewall refused, by rule (its index in the file, or default)."""
    refused = CounterMetricFamily(
        "mbgw_firewall_refused", "Requests the firewall refused (exception 0x01), by the rule "
        "that decided (its place among the [[rule]] tables, default, or no-role: a TLS "
        "client whose certificate has no role).", labels=["rule"])
    for rule in status["rules"]:
        refused.add_metric([str(rule["rule"])], rule["refused"])
    refused.add_metric(["default"], status["refused_default"])
    if status.get("require_role"):
        refused.add_metric(["no-role"], status["refused_no_role"])
    return refused

