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

# Function codes that change nothing in the device, so a request may be repeated as a probe
# (section 6): read coils, discrete inputs, holding and input registers, read exception
# status, get comm event counter, report server id, read file record, read FIFO queue,
# encapsulated interface (device identification).  By code: 1 when it writes nothing.
READ_ONLY = bytes(code in (0x01, 0x02, 0x03, 0x04, 0x07, 0x0B, 0x11, 0x14, 0x18, 0x2B)
                  for code in range(256))


def exception_pdu(function: int, code: int) -> bytes:
    return bytes((function | EXCEPTION_FLAG, code))
