"""Northbound MQTT, Sparkplug B 3.0 (issue 28), against Debian's Mosquitto: the gateway's
births, data and deaths as a subscriber decodes them with the compiled sparkplug_b.proto, its
commands (rebirth, writes reaching pymodbus's RTU slave, a write the firewall refuses), a
device demoted and answering again, the broker stopped and started again."""
import signal
import urllib.request

import pytest

from mbgw.northbound.sparkplug_b_pb2 import DataType, Payload
from tests.harness import free_port
from tests.integration.scenarios.test_scenarios_serial import poll, toml_value, write_config
from tests.ops import mbgw, status
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
def slave(pty_pair, start_peer):
    """pymodbus's RTU slave at address SLAVE on the line; slave[0] is the one running."""
    return [start_peer("pymodbus_slave.py", pty_pair.device, str(SLAVE))]


@pytest.fixture
def gateway(tmp_path, pty_pair, start_gateway, slave, broker):
    """gateway(extra, **mqtt) -> the gateway publishing the scenarios to the broker, with
    these [mqtt] keys and extra TOML after them."""

    def start(extra: str = "", down_after: int = 2, metrics: str | None = None, **mqtt):
        path = tmp_path / "mbgw.toml"
        write_config(path, scenarios(), metrics=metrics,
                     serial={"down-after": down_after, "probe-interval": 500})
        keys = {"broker": broker.url, "group": GROUP, "node": NODE, **mqtt}
        path.write_text(path.read_text() + "[mqtt]\n" +
                        "".join(f"{k} = {toml_value(v)}\n" for k, v in keys.items()) + extra)
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
    metrics_port = free_port()
    gw = gateway(metrics=f"127.0.0.1:{metrics_port}")
    until(lambda: read_all(sub), "every metric read", WAIT_S)
    # the scenarios poll every 100 ms and the slave's registers stay as they are: nothing
    # more is published however long the scenarios run
    runs = until(lambda: _runs(gw) >= 30 and _runs(gw), "30 runs", WAIT_S)
    published = len(sub.received())
    until(lambda: _runs(gw) >= runs + 20, "20 more runs", WAIT_S)
    assert len(sub.received()) == published
    assert status(gw)["mqtt"]["connected"] is True
    # what the subscriber got is what the gateway counts, in its status and on /metrics
    shown = mbgw("status", "--control", gw.control).stdout
    assert f"mqtt       {broker.url} sparkplug node {NODE}: connected" in shown
    with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=5) as r:
        text = r.read().decode()
    assert "mbgw_mqtt_connected 1.0" in text
    sent = status(gw)["mqtt"]["messages_sent"]
    assert f"mbgw_mqtt_messages_sent_total {float(sent)}" in text
    assert "mbgw_mqtt_commands_refused_total 0.0" in text


def _runs(gw) -> int:
    return sum(sc["runs"] for sc in status(gw)["scenarios"])


def command(kind: str, **values) -> bytes:
    """An NCMD or DCMD payload: metric name -> value (bool, int or float)."""
    out = Payload()
    for name, value in values.items():
        m = out.metrics.add()
        m.name = name
        if isinstance(value, bool):
            m.datatype, m.boolean_value = DataType.Boolean, value
        elif isinstance(value, int):
            m.datatype, m.int_value = DataType.UInt16, value
        else:
            m.datatype, m.float_value = DataType.Float, value
    return out.SerializeToString()


def test_ncmd_rebirth_births_everything_again_from_seq_0(gateway, broker, subscribe):
    sub = subscribe(broker.port, "spBv1.0/#")
    gateway()
    until(lambda: births(sub, "DBIRTH"), "a DBIRTH", WAIT_S)
    sub.publish(topic("NCMD"), command("NCMD", **{"Node Control/Rebirth": True}))
    until(lambda: len(births(sub, "NBIRTH")) == 2 and len(births(sub, "DBIRTH")) == 2,
          "a second NBIRTH and DBIRTH", WAIT_S)
    second = births(sub, "NBIRTH")[1]
    assert second.seq == 0 and metrics(second)["bdSeq"] == 0    # the same session
    assert births(sub, "DBIRTH")[1].seq == 1
    assert read_all(sub)["setpoint"] == 120


def test_dcmd_write_reaches_the_slave_through_the_firewall(gateway, broker, subscribe):
    rules = '[[rule]]\nrole = "scada"\nlistener = "mqtt"\n'
    sub = subscribe(broker.port, f"spBv1.0/{GROUP}/+/{NODE}/{DEVICE}")
    gw = gateway(rules, role="scada")
    until(lambda: read_all(sub), "every metric read", WAIT_S)
    sub.publish(topic("DCMD", DEVICE), command("DCMD", setpoint=4321))
    # the value comes back from the slave itself, read by the setpoint scenario
    until(lambda: any(metrics(p).get("setpoint") == 4321 for p in births(sub, "DDATA")),
          "the written setpoint read back from the slave", WAIT_S)
    assert status(gw)["mqtt"]["writes"] == 1


@pytest.mark.parametrize("role", [None, "viewer"])
def test_a_write_without_a_role_or_for_a_read_only_role_is_refused(gateway, broker,
                                                                   subscribe, role):
    rules = '[[rule]]\nrole = "viewer"\nread-only = true\n'
    sub = subscribe(broker.port, f"spBv1.0/{GROUP}/+/{NODE}/{DEVICE}")
    gw = gateway(rules, **({"role": role} if role else {}))
    until(lambda: read_all(sub), "every metric read", WAIT_S)
    sub.publish(topic("DCMD", DEVICE), command("DCMD", setpoint=4321))
    until(lambda: status(gw)["mqtt"]["commands_refused"] == 1, "the write refused", WAIT_S)
    assert "write refused" in gw.log()
    # the slave still has its value: the next reads publish no change
    runs = _runs(gw)
    until(lambda: _runs(gw) >= runs + 10, "10 more runs", WAIT_S)
    assert read_all(sub)["setpoint"] == 120
    assert status(gw)["mqtt"]["writes"] == 0


@pytest.mark.serial
def test_ddeath_when_the_slave_is_demoted_and_dbirth_when_it_answers_again(
        gateway, broker, subscribe, slave, pty_pair, start_peer):
    sub = subscribe(broker.port, f"spBv1.0/{GROUP}/+/{NODE}/{DEVICE}")
    gw = gateway()
    until(lambda: read_all(sub), "every metric read", WAIT_S)
    slave[0].stop()
    death = until(lambda: births(sub, "DDEATH"), "a DDEATH", WAIT_S)[0]
    demoted = until(lambda: _health(gw) == "down" and devices_of(gw)[SLAVE]["health_since"],
                    "the slave down", WAIT_S)
    # DDEATH's timestamp (the gateway's clock, ms) within a second of the demotion
    assert 0 <= death.timestamp / 1000 - demoted < 1.0
    slave[0] = start_peer("pymodbus_slave.py", pty_pair.device, str(SLAVE))
    until(lambda: len(births(sub, "DBIRTH")) == 2, "a DBIRTH on its return", WAIT_S)
    again = births(sub, "DBIRTH")[1]
    assert metrics(again)["Health"] in ("up", "degraded")
    kinds = [t.split("/")[2] for _, t, _, _ in sub.received()]
    assert kinds.index("DDEATH") < len(kinds) - 1 - kinds[::-1].index("DBIRTH")
    assert "DDATA" not in kinds[kinds.index("DDEATH"):len(kinds) - kinds[::-1].index("DBIRTH")]


def devices_of(gw) -> dict:
    return {d["address"]: d for d in status(gw)["devices"]}


def _health(gw) -> str | None:
    device = devices_of(gw).get(SLAVE)
    return None if device is None else device["health"]


def test_broker_restart_brings_births_back_and_no_flood(gateway, broker, subscribe):
    sub = subscribe(broker.port, "spBv1.0/#")
    gw = gateway()
    until(lambda: read_all(sub), "every metric read", WAIT_S)
    sub.close()
    broker.stop()
    # backoff 1 s, 2 s, 4 s: the broker comes back while the gateway waits 4 s
    until(lambda: "again in 4 s" in gw.log(), "the third reconnect delay", WAIT_S * 2)
    assert "again in 1 s" in gw.log() and "again in 2 s" in gw.log()
    broker.start()
    sub = subscribe(broker.port, "spBv1.0/#", client_id="test-subscriber-2")
    nbirth = until(lambda: births(sub, "NBIRTH"), "an NBIRTH after the restart", WAIT_S)[0]
    assert nbirth.seq == 0 and metrics(nbirth)["bdSeq"] > 0
    until(lambda: births(sub, "DBIRTH"), "a DBIRTH after the restart", WAIT_S)
    # the births carry the latest values; nothing from the outage follows them
    assert {k: v for k, v in metrics(births(sub, "DBIRTH")[0]).items()
            if k != "Health"} == {"temp": 100, "total": (102 << 16) | 103, "setpoint": 120}
    runs = _runs(gw)
    until(lambda: _runs(gw) >= runs + 20, "20 more runs", WAIT_S)
    assert [t.split("/")[2] for _, t, _, _ in sub.received()] == ["NBIRTH", "DBIRTH"]


def test_births_wait_for_the_primary_hosts_state_online(gateway, broker, subscribe):
    sub = subscribe(broker.port, "spBv1.0/#")
    gw = gateway(**{"primary-host": "scada1"})
    until(lambda: _runs(gw) >= 20, "20 runs", WAIT_S)
    assert not births(sub, "NBIRTH")
    state = "spBv1.0/STATE/scada1"
    sub.publish(state, '{"online": true, "timestamp": 1}', retain=True)
    until(lambda: births(sub, "NBIRTH") and births(sub, "DBIRTH"), "births", WAIT_S)
    # offline: the node ends its session (NDEATH, bdSeq 0) and waits in the next one
    sub.publish(state, '{"online": false, "timestamp": 2}', retain=True)
    death = until(lambda: births(sub, "NDEATH"), "an NDEATH", WAIT_S)[0]
    assert metrics(death) == {"bdSeq": 0}
    until(lambda: status(gw)["mqtt"]["connects"] == 2, "a new session", WAIT_S)
    assert len(births(sub, "NBIRTH")) == 1
    sub.publish(state, '{"online": true, "timestamp": 3}', retain=True)
    until(lambda: len(births(sub, "NBIRTH")) == 2, "births again after online", WAIT_S)
    again = births(sub, "NBIRTH")[1]
    assert again.seq == 0 and metrics(again)["bdSeq"] == 1


def test_stale_values_are_null_with_quality_500(gateway, broker, subscribe, slave):
    sub = subscribe(broker.port, f"spBv1.0/{GROUP}/+/{NODE}/{DEVICE}")
    gateway(down_after=0, **{"stale-after": 1000})   # never demoted: degraded, then stale
    until(lambda: read_all(sub), "every metric read", WAIT_S)
    slave[0].stop()

    def stale():
        """Every metric null, in one DDATA or over several (each goes stale on its own read's
        clock, so a tick may carry one before the others)."""
        found = {m.name: m for payload in births(sub, "DDATA") for m in payload.metrics
                 if m.is_null}
        return found if found.keys() >= {"temp", "total", "setpoint"} else None
    found = until(stale, "every metric stale", WAIT_S)
    for metric in found.values():
        assert list(metric.properties.keys) == ["Quality"]
        assert metric.properties.values[0].int_value == 500
    assert not births(sub, "DDEATH")


def test_a_reload_with_a_new_node_id_ends_the_old_node_and_births_the_new(
        gateway, broker, subscribe, tmp_path):
    sub = subscribe(broker.port, "spBv1.0/#")
    gw = gateway()
    until(lambda: births(sub, "DBIRTH"), "a DBIRTH", WAIT_S)
    path = tmp_path / "mbgw.toml"
    path.write_text(path.read_text().replace(f'node = "{NODE}"', 'node = "gw2"'))
    gw.proc.send_signal(signal.SIGHUP)
    until(lambda: any(t == "spBv1.0/plant1/NBIRTH/gw2" for _, t, _, _ in sub.received()),
          "gw2's NBIRTH", WAIT_S)
    assert [t for _, t, _, _ in sub.received("NDEATH")] == [topic("NDEATH")]
    assert status(gw)["mqtt"]["node"] == "gw2"
