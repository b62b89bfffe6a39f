"""The JSON profile's line states in the status (issue 30's Lines page): each as the broker
last got it under GROUP/NODE/Lines/NAME/State, a refused publish not counted as got, a line
a reload took away gone."""
from mbgw.config.mqtt import MqttConfig
from mbgw.northbound.counters import NorthboundCounters
from mbgw.northbound.json_node import JsonNode
from mbgw.northbound.sampler import Sampler
from tests.unit.northbound.test_edge_node import Table


class Session:
    def __init__(self) -> None:
        self.open = True
        self.sent: dict[str, str] = {}

    def publish(self, topic: str, payload: str, qos: int = 0, retain: bool = False) -> bool:
        if self.open:
            self.sent[topic] = payload
        return self.open


def test_the_status_has_each_line_s_state_as_the_broker_last_got_it():
    counters = NorthboundCounters()
    node = JsonNode(MqttConfig(broker="mqtt://x", group="g", node="n", profile="json"), "n",
                    {}, Sampler(Table(), {}, 0), counters)
    session = Session()
    node.connected(session)
    node.tick(session, {"serial": "up", "meters": "up"})
    assert counters.snapshot()["lines"] == {"serial": "up", "meters": "up"}
    assert '"value": "up"' in session.sent["g/n/Lines/meters/State"]
    session.open = False                          # refused: the broker still has "up"
    node.tick(session, {"serial": "up", "meters": "down"})
    assert counters.snapshot()["lines"] == {"serial": "up", "meters": "up"}
    session.open = True
    node.tick(session, {"serial": "up", "meters": "down"})
    assert counters.snapshot()["lines"] == {"serial": "up", "meters": "down"}
    node.tick(session, {"serial": "up"})          # meters taken away by a reload
    assert counters.snapshot()["lines"] == {"serial": "up"}
