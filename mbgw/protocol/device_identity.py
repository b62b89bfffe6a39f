"""What a device's identity replies say (Modbus Application Protocol V1.1b3): FC 43/14 Read
Device Identification (6.21) and FC 17 Report Server ID (6.13).  No I/O."""

# the basic objects of read code 01 (6.21, table "Basic")
BASIC_OBJECTS = {0x00: "vendor", 0x01: "product_code", 0x02: "revision"}
# the reply's head: function, MEI type, read code, conformity, more follows, next object id,
# number of objects
_IDENTIFICATION_HEAD = 7


def identification_objects(pdu: bytes) -> dict[str, str] | None:
    """The objects of a FC 43/14 reply PDU by name (basic ones as BASIC_OBJECTS names them,
    others as "object 0xNN"); None when pdu is no such reply (an exception, a short one)."""
    if len(pdu) < _IDENTIFICATION_HEAD or pdu[0] != 0x2B or pdu[1] != 0x0E:
        return None
    objects: dict[str, str] = {}
    at = _IDENTIFICATION_HEAD
    for _ in range(pdu[6]):
        if at + 2 > len(pdu):
            return None
        object_id, length = pdu[at], pdu[at + 1]
        value = pdu[at + 2:at + 2 + length]
        if len(value) < length:
            return None
        objects[BASIC_OBJECTS.get(object_id, f"object 0x{object_id:02x}")] = \
            value.decode("latin-1")
        at += 2 + length
    return objects


def server_id(pdu: bytes) -> dict[str, str] | None:
    """A FC 17 reply PDU's data (server id, run indicator, the rest; their layout is the
    device's own) as hex and as printable ASCII ('.' for the other bytes); None when pdu is
    no such reply."""
    if len(pdu) < 2 or pdu[0] != 0x11 or len(pdu) < 2 + pdu[1]:
        return None
    data = pdu[2:2 + pdu[1]]
    return {"server_id": data.hex(" "),
            "text": "".join(chr(b) if 0x20 <= b < 0x7F else "." for b in data)}
