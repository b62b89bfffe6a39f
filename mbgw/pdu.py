"""Modbus PDU facts the gateway needs (Modbus Application Protocol V1.1b3)."""

BROADCAST = 0                 # serial address 0 (Serial Line V1.02, 2.2)
MAX_SERIAL_ADDRESS = 247      # 248..255 are reserved on a serial line
EXCEPTION_FLAG = 0x80

# Exception codes a gateway generates (section 7)
GATEWAY_PATH_UNAVAILABLE = 0x0A
GATEWAY_TARGET_FAILED = 0x0B

# Function codes whose replies libmodbus 3.1.6 frames correctly (see notes/libmodbus.md 1.4);
# replies to every other code are framed by our own C.
LIBMODBUS_FRAMED = frozenset({0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07,
                              0x0F, 0x10, 0x11, 0x16, 0x17})


def exception_pdu(function: int, code: int) -> bytes:
    return bytes((function | EXCEPTION_FLAG, code))


def reply_matches(req: bytes, rsp: bytes) -> bool:
    """True when the reply PDU rsp can be the answer to the request PDU req.

    An exception for the request's function always matches; a normal reply must carry the
    request's function and, for the standard data access codes, the size or echo that the
    request asked for.
    """
    function = req[0]
    if rsp[0] == function | EXCEPTION_FLAG:
        return len(rsp) == 2
    if rsp[0] != function:
        return False
    if function in (0x01, 0x02) and len(req) >= 5:
        quantity = int.from_bytes(req[3:5], "big")
        return rsp[1] == (quantity + 7) // 8 and len(rsp) == 2 + rsp[1]
    if function in (0x03, 0x04) and len(req) >= 5:
        quantity = int.from_bytes(req[3:5], "big")
        return rsp[1] == 2 * quantity and len(rsp) == 2 + rsp[1]
    if function in (0x05, 0x06, 0x0F, 0x10):
        return len(rsp) == 5 and rsp[1:5] == req[1:5]
    if function == 0x16:
        return rsp == req
    if function == 0x17 and len(req) >= 5:
        quantity = int.from_bytes(req[3:5], "big")
        return rsp[1] == 2 * quantity and len(rsp) == 2 + rsp[1]
    return True
