"""The edge node's rules with the table and the session stood in for: a slow broker's
refusals dropped and counted while the last published values stay, so the next DDATA
carries the latest; seq moving only with what was sent (issue 28)."""
from mbgw.config.mqtt import MqttConfig
from mbgw.config.scenario import parse_scenario
from mbgw.northbound.catalogue import devices
from mbgw.northbound.counters import NorthboundCounters
from mbgw.northbound.edge_node import EdgeNode
from mbgw.northbound.sampler import Sampler
from mbgw.northbound.sparkplug_b_pb2 import Payload


class Table:
    def __init__(self) -> None:
        self.registers = [0] * 16

    def read(self, first: int, count: int) -> list[int]:
        return self.registers[first:first + count]


class Engine:
    health = None

    def data_ages(self) -> dict:
        return {"a": 0.0}


class Session:
    """Takes publishes while open; refuses them (a broker too slow) while not."""

    def __init__(self) -> None:
        self.open = True
        self.sent: list[tuple[str, Payload]] = []

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> bool:
        if not self.open:
            return False
        decoded = Payload()
        decoded.ParseFromString(payload)
        self.sent.append((topic.split("/")[2], decoded))
        return True


def node() -> tuple[EdgeNode, Table, Session, NorthboundCounters]:
    sc = parse_scenario({"name": "a", "slave": 5, "function": 3, "address": 0, "quantity": 1,
                         "table": 3, "cycle": 1000}, "s")
    table, counters = Table(), NorthboundCounters()
    edge = EdgeNode(MqttConfig(broker="mqtt://x", group="g", node="n"), "n",
                    devices([sc]), Sampler(table, {"serial": Engine()}, 0), counters)
    session = Session()
    edge.connected(session)
    return edge, table, session, counters


def test_a_slow_broker_drops_values_and_the_next_ddata_carries_the_latest():
    edge, table, session, counters = node()
    edge.tick(session, {"serial": "up"})
    assert [k for k, _ in session.sent] == ["NBIRTH", "DBIRTH"]
    session.open = False
    for value in (1, 2, 3):
        table.registers[3] = value
        edge.tick(session, {"serial": "up"})
    assert counters.dropped == 3
    session.open = True
    edge.tick(session, {"serial": "up"})
    kind, ddata = session.sent[-1]
    assert kind == "DDATA" and [(m.name, m.int_value) for m in ddata.metrics] == [("a", 3)]
    assert [p.seq for _, p in session.sent] == [0, 1, 2]     # refused messages took no seq
    edge.tick(session, {"serial": "up"})
    assert len(session.sent) == 3                            # nothing moved: nothing sent


def test_a_line_state_change_is_ndata():
    edge, _, session, _ = node()
    edge.tick(session, {"serial": "up"})
    edge.tick(session, {"serial": "down"})
    kind, ndata = session.sent[-1]
    assert kind == "NDATA"
    assert [(m.name, m.string_value) for m in ndata.metrics] == [("Lines/serial/State", "down")]


def test_the_status_has_each_line_s_state_as_the_broker_last_got_it():
    edge, _, session, counters = node()
    edge.tick(session, {"serial": "up", "meters": "up"})
    assert counters.snapshot()["lines"] == {"serial": "up", "meters": "up"}
    session.open = False                             # the NDATA refused: the broker has "up"
    edge.tick(session, {"serial": "up", "meters": "down"})
    assert counters.snapshot()["lines"] == {"serial": "up", "meters": "up"}
    session.open = True
    edge.tick(session, {"serial": "up", "meters": "down"})
    assert counters.snapshot()["lines"] == {"serial": "up", "meters": "down"}
