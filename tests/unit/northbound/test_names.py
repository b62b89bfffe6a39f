"""The edge node's default id and the devices' ids (issue 28)."""
import socket

from mbgw.config.scenario import parse_scenario
from mbgw.northbound.names import default_node, device_id


def test_the_node_is_the_short_host_name_and_host_name_for_an_instance(monkeypatch):
    monkeypatch.setattr(socket, "gethostname", lambda: "gw-hall3.plant.example")
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    assert default_node() == "gw-hall3"
    monkeypatch.setenv("RUNTIME_DIRECTORY", "/run/mbgw/ttyUSB1")    # mbgw@ttyUSB1
    assert default_node() == "gw-hall3-ttyUSB1"
    monkeypatch.setenv("RUNTIME_DIRECTORY", "/run/mbgw")             # mbgw.service
    assert default_node() == "gw-hall3"


def test_device_ids():
    def scenario(**target):
        return parse_scenario({"name": "a", "function": 3, "address": 0, "quantity": 1,
                               "table": 0, "cycle": 1000, **target}, "s")
    assert device_id(scenario(slave=5)) == "serial-5"
    assert device_id(scenario(server="10.0.0.7:1502", unit=3)) == "tcp-10.0.0.7-1502-3"
    assert device_id(scenario(server="[fd00::7]", unit=1)) == "tcp-fd00--7-502-1"
