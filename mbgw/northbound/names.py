"""What the gateway is called northbound: its edge node id by default, and the device id of
each scenario's target."""
import os
import socket

from mbgw.config.scenario import ScenarioConfig
from mbgw.config.server_address import split_server

PRIMARY_LINE = "serial"          # the line serial scenarios run on


def default_node() -> str:
    """The short host name; HOST-NAME for the instance mbgw@NAME (its RuntimeDirectory=
    is mbgw/NAME)."""
    host = socket.gethostname().split(".", 1)[0] or "mbgw"
    runtime = os.environ.get("RUNTIME_DIRECTORY", "").rstrip("/")
    parent, _, instance = runtime.rpartition("/")
    if instance and parent.endswith("/mbgw"):
        return f"{host}-{instance}"
    return host


def device_id(sc: ScenarioConfig) -> str:
    """serial-5 for serial address 5 of line serial; tcp-HOST-PORT-UNIT for a TCP
    scenario (an IPv6 host's colons as dashes)."""
    if sc.slave is not None:
        return f"{PRIMARY_LINE}-{sc.slave}"
    host, port = split_server(sc.server or "")
    return f"tcp-{host.replace(':', '-').replace('%', '-')}-{port}-{sc.unit}"
