"""Northbound MQTT, Sparkplug B 3.0 (issue 28), against Debian's Mosquitto: the gateway's
births, data and deaths as a subscriber decodes them with the compiled sparkplug_b.proto, its
commands (rebirth, writes reaching pymodbus's RTU slave, a write the firewall refuses), a
device demoted and answering again, the broker stopped and started again."""
import signal

import pytest

from mbgw.northbound.sparkplug_b_pb2 import DataType, Payload
from tests.integration.scenarios.test_scenarios_serial import poll, write_config
from tests.ops import status
from tests.wait import until

pytestmark = pytest.mark.integration

SLAVE = 5                    # pymodbus: holding register n holds 100 + n
WAIT_S = 10.0
GROUP, NODE = "plant1", "gw1"
DEVICE = f"serial-{SLAVE}"


def decode(payload: bytes) -> Payload:
    out = Payload()
    out.ParseFromString(payload)
    return out


def metrics(payload: Payload) -> dict:
    """name -> value (None for is_null) of a payload's metrics."""
    out = {}
    for m in payload.metrics:
        which = m.WhichOneof("value")
        out[m.name] = None if m.is_null or which is None else getattr(m, which)
    return out


def topic(kind: str, device: str | None = None) -> str:
    return f"spBv1.0/{GROUP}/{kind}/{NODE}" + (f"/{device}" if device else "")


def scenarios() -> list[dict]:
    return [poll("temp", SLAVE, 3, 0, 1, 0, type="int16"),
            poll("total", SLAVE, 3, 2, 2, 10, type="uint32"),
            poll("setpoint", SLAVE, 3, 20, 1, 20)]


@pytest.fixture
def gateway(tmp_path, pty_pair, start_gateway, start_peer, broker):
    """gateway(**mqtt) -> the gateway publishing the scenarios to the broker, pymodbus's
    slave on the line."""
    start_peer("pymodbus_slave.py", pty_pair.device, str(SLAVE))

    def start(extra: str = "", **mqtt):
        path = tmp_path / "mbgw.toml"
        write_config(path, scenarios(), serial={"down-after": 2, "probe-interval": 500})
        keys = {"broker": broker.url, "group": GROUP, "node": NODE, **mqtt}
        path.write_text(path.read_text() + "[mqtt]\n" +
                        "".join(f'{k} = "{v}"\n' for k, v in keys.items()) + extra)
        return start_gateway(pty_pair.gateway, "--config", str(path))
    return start


def births(sub, kind: str) -> list[Payload]:
    return [decode(p) for _, t, p, _ in sub.received(f"/{kind}/")]


def test_nbirth_then_dbirth_with_every_metric_and_the_will_on_a_crash(gateway, broker,
                                                                      subscribe):
    sub = subscribe(broker.port, "spBv1.0/#")
    gw = gateway()
    nbirth = until(lambda: births(sub, "NBIRTH"), "an NBIRTH", WAIT_S)[0]
    assert nbirth.seq == 0
    node = metrics(nbirth)
    assert node["bdSeq"] == 0 and node["Node Control/Rebirth"] is False
    assert node["Lines/serial/State"] in ("up", "starting", "open")
    dbirth = until(lambda: births(sub, "DBIRTH"), "a DBIRTH", WAIT_S)[0]
    assert dbirth.seq == 1
    assert set(metrics(dbirth)) == {"Health", "temp", "total", "setpoint"}
    types = {m.name: m.datatype for m in dbirth.metrics}
    assert types == {"Health": DataType.String, "temp": DataType.Int16,
                     "total": DataType.UInt32, "setpoint": DataType.UInt16}
    values = until(lambda: read_all(sub), "every metric read", WAIT_S)
    assert values["temp"] == 100 and values["total"] == (102 << 16) | 103
    assert values["setpoint"] == 120
    seqs = [decode(p).seq for _, t, p, _ in sub.received() if "NDEATH" not in t]
    assert seqs == [n % 256 for n in range(len(seqs))]
    assert len(births(sub, "NBIRTH")) == 1 and len(births(sub, "DBIRTH")) == 1
    gw.proc.send_signal(signal.SIGKILL)
    gw.proc.wait()
    death = until(lambda: births(sub, "NDEATH"), "the Will (NDEATH)", WAIT_S)[0]
    assert metrics(death) == {"bdSeq": 0}


def read_all(sub) -> dict | None:
    """The device's values so far (births and data), once every metric has one."""
    values = {}
    for payload in births(sub, "DBIRTH") + births(sub, "DDATA"):
        values.update({k: v for k, v in metrics(payload).items() if v is not None})
    return values if values.keys() >= {"temp", "total", "setpoint"} else None


def test_ddata_only_on_change(gateway, broker, subscribe):
    sub = subscribe(broker.port, f"spBv1.0/{GROUP}/+/{NODE}/{DEVICE}")
    gw = gateway()
    until(lambda: read_all(sub), "every metric read", WAIT_S)
    # the scenarios poll every 100 ms and the slave's registers stay as they are: nothing
    # more is published however long the scenarios run
    runs = until(lambda: _runs(gw) >= 30 and _runs(gw), "30 runs", WAIT_S)
    published = len(sub.received())
    until(lambda: _runs(gw) >= runs + 20, "20 more runs", WAIT_S)
    assert len(sub.received()) == published
    assert status(gw)["mqtt"]["connected"] is True


def _runs(gw) -> int:
    return sum(sc["runs"] for sc in status(gw)["scenarios"])
