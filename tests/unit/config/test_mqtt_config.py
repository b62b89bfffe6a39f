"""[mqtt]: the broker's URL, the ids, the client certificate's pair (issue 28)."""
import pytest

from mbgw.config.mqtt import MqttConfig, broker_address
from mbgw.errors import ConfigError


@pytest.mark.parametrize("url, expected", [
    ("mqtt://broker.plant", ("mqtt", "broker.plant", 1883)),
    ("mqtts://broker.plant:8884", ("mqtts", "broker.plant", 8884)),
    ("mqtt://[::1]:1884", ("mqtt", "::1", 1884)),
])
def test_broker_urls(url, expected):
    assert broker_address(url) == expected


@pytest.mark.parametrize("url", ["http://x", "mqtt://", "mqtt://x:99999", "mqtt://x/path",
                                 "mqtt://user@x", "broker:1883"])
def test_a_broker_that_is_not_an_mqtt_url_is_refused(url):
    with pytest.raises(ConfigError, match=r"^mqtt\.broker: "):
        MqttConfig(broker=url)


@pytest.mark.parametrize("changes, key", [
    ({"node": "a/b"}, "mqtt.node"), ({"group": "plant#1"}, "mqtt.group"),
    ({"primary-host": "+"}, "mqtt.primary-host"), ({"profile": "xml"}, "mqtt.profile"),
    ({"cert": "/c.pem"}, "mqtt.cert"), ({"stale-after": -1}, "mqtt.stale-after"),
])
def test_bad_values_name_their_key(changes, key):
    kwargs = {k.replace("-", "_") + ("_ms" if k == "stale-after" else ""): v
              for k, v in changes.items()}
    with pytest.raises(ConfigError, match=rf"^{key}: "):
        MqttConfig(broker="mqtt://x", **kwargs)


def test_off_unless_a_broker_is_set():
    assert not MqttConfig().enabled
    assert MqttConfig(broker="mqtts://x").tls and not MqttConfig(broker="mqtt://x").tls
