"""Reading a device's identity replies (mbgw.protocol.device_identity), from replies built by
hand after the Modbus Application Protocol V1.1b3, 6.21 and 6.13."""
from mbgw.protocol.device_identity import identification_objects, server_id


def objects(*pairs: tuple[int, bytes]) -> bytes:
    return b"".join(bytes((oid, len(value))) + value for oid, value in pairs)


def test_read_device_identification_names_the_basic_objects():
    body = objects((0, b"Acme"), (1, b"PX-1"), (2, b"1.2"))
    pdu = bytes((0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 3)) + body
    assert identification_objects(pdu) == {"vendor": "Acme", "product_code": "PX-1",
                                           "revision": "1.2"}


def test_other_objects_by_their_id():
    pdu = bytes((0x2B, 0x0E, 0x04, 0x83, 0x00, 0x00, 1)) + objects((0x80, b"x"))
    assert identification_objects(pdu) == {"object 0x80": "x"}


def test_what_is_no_identification_reply_is_none():
    assert identification_objects(bytes((0xAB, 0x01))) is None                   # exception
    assert identification_objects(bytes((0x2B, 0x0D, 1, 1, 0, 0, 0))) is None    # MEI 13
    short = bytes((0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 2)) + objects((0, b"Acme"))
    assert identification_objects(short) is None
    assert identification_objects(short[:-1][:9] + bytes((9,)) + b"ab") is None


def test_report_server_id_as_hex_and_printable_ascii():
    pdu = bytes((0x11, 5, 0x2A)) + b"AB\x00" + b"\xff"
    assert server_id(pdu) == {"server_id": "2a 41 42 00 ff", "text": "*AB.."}
    assert server_id(bytes((0x91, 0x01))) is None
    assert server_id(bytes((0x11, 5, 1))) is None
