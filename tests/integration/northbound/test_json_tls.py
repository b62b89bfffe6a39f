"""Northbound MQTT's JSON profile (retained GROUP/NODE/DEVICE/METRIC topics, writes on
.../set, the status topic as the Will, Home Assistant discovery) and TLS to the broker with
a client certificate, against Debian's Mosquitto (issue 28)."""
import json
import signal

import pytest

from tests.integration.northbound.test_sparkplug import SLAVE, scenarios
from tests.integration.scenarios.test_scenarios_serial import toml_value, write_config
from tests.ops import status
from tests.peers.broker import Broker
from tests.pki import Authority
from tests.wait import until

pytestmark = pytest.mark.integration

WAIT_S = 10.0
GROUP, NODE = "plant1", "gw1"
DEVICE = f"serial-{SLAVE}"
BASE = f"{GROUP}/{NODE}"


@pytest.fixture
def config(tmp_path, pty_pair, start_peer):
    """config(url, extra, **mqtt) -> a configuration file for these [mqtt] keys."""
    start_peer("pymodbus_slave.py", pty_pair.device, str(SLAVE))

    def write(url: str, extra: str = "", **mqtt) -> str:
        path = tmp_path / "mbgw.toml"
        write_config(path, scenarios())
        keys = {"broker": url, "group": GROUP, "node": NODE, **mqtt}
        path.write_text(path.read_text() + "[mqtt]\n" +
                        "".join(f"{k} = {toml_value(v)}\n" for k, v in keys.items()) + extra)
        return str(path)
    return write


def latest(sub, topic: str):
    found = [p for _, t, p, _ in sub.received() if t == topic]
    return json.loads(found[-1]) if found else None


def test_json_topics_writes_and_home_assistant_discovery(config, broker, subscribe,
                                                         start_gateway, pty_pair):
    rules = '[[rule]]\nrole = "scada"\nlistener = "mqtt"\n'
    sub = subscribe(broker.port, f"{BASE}/#", "homeassistant/#")
    gw = start_gateway(pty_pair.gateway, "--config",
                       config(broker.url, rules, profile="json", role="scada"))
    temp = until(lambda: (v := latest(sub, f"{BASE}/{DEVICE}/temp")) and v["value"] is not None
                 and v, "temp published", WAIT_S)
    assert temp["value"] == 100 and temp["quality"] == "good"
    assert isinstance(temp["timestamp"], int)
    assert latest(sub, f"{BASE}/{DEVICE}/Health")["value"] in ("up", "degraded")
    assert [p for _, t, p, _ in sub.received() if t == f"{BASE}/status"] == [b"online"]
    # Home Assistant: one retained config per metric, republished when it comes online
    topic = f"homeassistant/number/{NODE}/{DEVICE}_temp/config"
    discovery = until(lambda: latest(sub, topic), "the discovery of temp", WAIT_S)
    assert discovery["state_topic"] == f"{BASE}/{DEVICE}/temp"
    assert discovery["value_template"] == "{{ value_json.value }}"
    assert discovery["command_topic"] == f"{BASE}/{DEVICE}/temp/set"
    assert discovery["availability_topic"] == f"{BASE}/status"
    assert discovery["unique_id"] and discovery["device"]["identifiers"]
    configs = len(sub.received("homeassistant/number/"))
    assert configs == 3                                # temp, total, setpoint
    sub.publish("homeassistant/status", "online")
    until(lambda: len(sub.received("homeassistant/number/")) == 2 * configs,
          "the discovery again", WAIT_S)
    # a write on .../set, read back from the slave
    sub.publish(f"{BASE}/{DEVICE}/setpoint/set", json.dumps({"value": 77}))
    until(lambda: (latest(sub, f"{BASE}/{DEVICE}/setpoint") or {}).get("value") == 77,
          "the written setpoint read back", WAIT_S)
    sub.publish(f"{BASE}/{DEVICE}/setpoint/set", "78")
    until(lambda: (latest(sub, f"{BASE}/{DEVICE}/setpoint") or {}).get("value") == 78,
          "a bare value written", WAIT_S)
    gw.proc.send_signal(signal.SIGKILL)
    gw.proc.wait()
    until(lambda: [p for _, t, p, _ in sub.received() if t == f"{BASE}/status"][-1]
          == b"offline", "the Will: offline", WAIT_S)


def test_retained_values_reach_a_late_subscriber(config, broker, subscribe, start_gateway,
                                                 pty_pair):
    gw = start_gateway(pty_pair.gateway, "--config", config(broker.url, profile="json"))
    until(lambda: status(gw)["mqtt"]["messages_sent"] > 5, "values published", WAIT_S)
    late = subscribe(broker.port, f"{BASE}/{DEVICE}/#", client_id="late")
    temp = until(lambda: latest(late, f"{BASE}/{DEVICE}/temp"), "the retained temp", WAIT_S)
    assert all(retained for _, _, _, retained in late.received())
    assert temp["value"] in (100, None)


def test_tls_to_the_broker_with_a_client_certificate(tmp_path, config, start_gateway,
                                                     pty_pair, subscribe):
    ca = Authority(tmp_path)
    server = ca.issue("broker", server=True)
    client = ca.issue("gw1")
    reader = ca.issue("reader")
    broker = Broker(tmp_path, tls=(*server, ca.cert))
    try:
        sub = subscribe(broker.port, f"{BASE}/#", tls=(*reader, ca.cert))
        gw = start_gateway(pty_pair.gateway, "--config", config(
            broker.url, profile="json", cert=str(client[0]), key=str(client[1]), ca=str(ca.cert)))
        until(lambda: (v := latest(sub, f"{BASE}/{DEVICE}/temp")) and v["value"] == 100,
              "temp over TLS", WAIT_S)
        assert status(gw)["mqtt"]["connected"] is True
        assert "gw1" in broker.log()
    finally:
        broker.stop()


def test_tls_refused_without_the_brokers_ca(tmp_path, config, start_gateway, pty_pair):
    ca = Authority(tmp_path)
    other = Authority(tmp_path, "other")
    server = ca.issue("broker", server=True)
    client = ca.issue("gw1")
    broker = Broker(tmp_path, tls=(*server, ca.cert))
    try:
        gw = start_gateway(pty_pair.gateway, "--config", config(
            broker.url, profile="json", cert=str(client[0]), key=str(client[1]),
            ca=str(other.cert)))
        until(lambda: "CERTIFICATE_VERIFY_FAILED" in gw.log() or "certificate verify"
              in gw.log(), "the broker's certificate refused", WAIT_S)
        assert status(gw)["mqtt"]["connected"] is False
    finally:
        broker.stop()
