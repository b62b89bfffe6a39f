"""Sparkplug B payloads as a host decodes them (the compiled Tahu proto): births, stale
values, commands, report by exception with a deadband (issue 28)."""
from mbgw.northbound import sparkplug
from mbgw.northbound.sampler import Reading, moved
from mbgw.northbound.sparkplug_b_pb2 import DataType, Payload


def decoded(data: bytes) -> Payload:
    out = Payload()
    out.ParseFromString(data)
    return out


def test_ndeath_carries_bdseq_and_no_seq():
    death = decoded(sparkplug.death(7))
    assert not death.HasField("seq")
    assert [(m.name, m.datatype, m.long_value) for m in death.metrics] == \
        [("bdSeq", DataType.Int64, 7)]


def test_nbirth_has_rebirth_and_the_lines():
    birth = decoded(sparkplug.node_birth(0, 3, {"serial": "up"}))
    assert birth.seq == 0
    assert {m.name: m.WhichOneof("value") for m in birth.metrics} == {
        "bdSeq": "long_value", "Node Control/Rebirth": "boolean_value",
        "Lines/serial/State": "string_value"}


def test_stale_is_null_with_quality_500_and_unread_is_null_alone():
    data = decoded(sparkplug.device_payload(4, "up", [
        ("a", "int16", Reading(-2)), ("b", "float32", Reading(None, stale=True)),
        ("c", "uint16", Reading(None))]))
    a, b, c = data.metrics[1:]
    assert a.datatype == DataType.Int16 and a.int_value == 0xFFFFFFFE   # two's complement
    assert b.is_null and list(b.properties.keys) == ["Quality"]
    assert b.properties.values[0].type == DataType.Int32
    assert b.properties.values[0].int_value == 500
    assert c.is_null and not c.properties.keys


def test_command_values_read_signed_ints_back():
    out = Payload()
    m = out.metrics.add()
    m.name, m.datatype, m.int_value = "t", DataType.Int16, 0xFFFFFFFE
    assert sparkplug.command_values(out.SerializeToString()) == [("t", -2)]


def test_report_by_exception_with_a_deadband():
    assert moved(None, Reading(1), 0)
    assert not moved(Reading(1), Reading(1), 0)
    assert not moved(Reading(10.0), Reading(10.4), 0.5)
    assert moved(Reading(10.0), Reading(10.6), 0.5)
    assert moved(Reading(10.0), Reading(None, stale=True), 0.5)
    assert moved(Reading("a"), Reading("b"), 0)
