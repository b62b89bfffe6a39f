"""Sparkplug B 3.0 payloads and topics (Eclipse Sparkplug 3.0.0, chapter 6), encoded with
Eclipse Tahu's sparkplug_b.proto: births with every metric, data, deaths, the commands'
metrics.  Int8/16/32 go in int_value as two's complement, as Tahu does."""
import json
import time

from mbgw.northbound.catalogue import HEALTH
from mbgw.northbound.sampler import Reading
from mbgw.northbound.sparkplug_b_pb2 import DataType, Payload

NAMESPACE = "spBv1.0"
REBIRTH = "Node Control/Rebirth"
BDSEQ = "bdSeq"
QUALITY = "Quality"
QUALITY_STALE = 500                # Sparkplug 3.0 §6.4.17: a stale value's quality
DATATYPES = {"uint16": DataType.UInt16, "int16": DataType.Int16, "uint32": DataType.UInt32,
             "int32": DataType.Int32, "float32": DataType.Float, "bool": DataType.Boolean,
             "string": DataType.String}


def topic(group: str, kind: str, node: str, device: str | None = None) -> str:
    return f"{NAMESPACE}/{group}/{kind}/{node}" + (f"/{device}" if device else "")


def state_topic(host: str) -> str:
    """Sparkplug 3.0 §6.4.10: the primary host application's STATE."""
    return f"{NAMESPACE}/STATE/{host}"


def now_ms() -> int:
    return int(time.time() * 1000)


def payload(seq: int | None, timestamp: int | None = None) -> Payload:
    out = Payload()
    out.timestamp = now_ms() if timestamp is None else timestamp
    if seq is not None:
        out.seq = seq
    return out


def add_metric(out: Payload, name: str, kind: str, reading: Reading, timestamp: int) -> None:
    metric = out.metrics.add()
    metric.name = name
    metric.timestamp = timestamp
    metric.datatype = DATATYPES[kind]
    value = reading.value
    if value is None:
        metric.is_null = True
        if reading.stale:
            metric.properties.keys.append(QUALITY)
            quality = metric.properties.values.add()
            quality.type = DataType.Int32
            quality.int_value = QUALITY_STALE
    elif kind == "bool":
        metric.boolean_value = bool(value)
    elif kind == "string":
        metric.string_value = str(value)
    elif kind == "float32":
        metric.float_value = float(value)
    else:
        metric.int_value = int(value) & 0xFFFFFFFF


def add_string(out: Payload, name: str, text: str, timestamp: int) -> None:
    add_metric(out, name, "string", Reading(text), timestamp)


def add_bdseq(out: Payload, bdseq: int, timestamp: int) -> None:
    metric = out.metrics.add()
    metric.name = BDSEQ
    metric.timestamp = timestamp
    metric.datatype = DataType.Int64
    metric.long_value = bdseq


def death(bdseq: int) -> bytes:
    """NDEATH, the MQTT Will: its bdSeq and no seq (§6.4.7)."""
    out = payload(None)
    add_bdseq(out, bdseq, out.timestamp)
    return out.SerializeToString()


def node_birth(seq: int, bdseq: int, lines: dict[str, str]) -> bytes:
    out = payload(seq)
    add_bdseq(out, bdseq, out.timestamp)
    add_metric(out, REBIRTH, "bool", Reading(False), out.timestamp)
    for name, state in lines.items():
        add_string(out, line_metric(name), state, out.timestamp)
    return out.SerializeToString()


def line_metric(name: str) -> str:
    return f"Lines/{name}/State"


def device_payload(seq: int, health: str | None, metrics) -> bytes:
    """DBIRTH or DDATA: the Health metric (None: unchanged) and metrics, (name, kind,
    Reading) each."""
    out = payload(seq)
    if health is not None:
        add_string(out, HEALTH, health, out.timestamp)
    for name, kind, reading in metrics:
        add_metric(out, name, kind, reading, out.timestamp)
    return out.SerializeToString()


def node_data(seq: int, lines: dict[str, str]) -> bytes:
    out = payload(seq)
    for name, state in lines.items():
        add_string(out, line_metric(name), state, out.timestamp)
    return out.SerializeToString()


def bare(seq: int) -> bytes:
    """DDEATH: a timestamp and the seq (§6.4.12)."""
    return payload(seq).SerializeToString()


def command_values(data: bytes) -> list[tuple[str, object]]:
    """NCMD/DCMD: (metric name, value) of each metric that has one.  Raises ValueError for a
    payload that is not Sparkplug."""
    received = Payload()
    try:
        received.ParseFromString(data)
    except Exception as err:        # protobuf's DecodeError, whose module differs by version
        raise ValueError(f"not a Sparkplug B payload ({err})") from None
    out: list[tuple[str, object]] = []
    for metric in received.metrics:
        which = metric.WhichOneof("value")
        if which is None or metric.is_null:
            continue
        value = getattr(metric, which)
        if which == "int_value" and metric.datatype in (DataType.Int8, DataType.Int16,
                                                        DataType.Int32):
            value = value - (1 << 32) if value & 0x80000000 else value
        out.append((metric.name, value))
    return out


def host_online(data: bytes) -> bool | None:
    """A STATE payload's online flag (§6.4.10: JSON {"online": bool, "timestamp": ms});
    None when it is not one."""
    try:
        state = json.loads(data)
    except ValueError:
        return None
    online = state.get("online") if isinstance(state, dict) else None
    return online if isinstance(online, bool) else None

