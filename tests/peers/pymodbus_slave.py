"""A real serial slave that is not our code: pymodbus's RTU server on a pty.

usage: pymodbus_slave.py DEVICE [ADDRESS...] [--identity] [--silent-unknown] [--record PATH]
                           [--record-replies] [--stamp] [--holding N]  (default address 17)
Holding registers 0..99 hold 100..199 (N..N+99 with --holding N), input registers 0..99
hold 1000..1099, coils and discrete inputs alternate 1, 0 from address 0.  Broadcasts
(address 0) are executed on every address.  Prints READY when listening.

--identity        serve IDENTITY below for FC 0x2B/0x0E (read device identification) and FC 0x11
                  (report server id); without it pymodbus has no objects.
--silent-unknown  stay silent for a request to an address this server does not have, as a real
                  line does (pymodbus 3.16.1 otherwise answers such a request with exception 0x04).
--record PATH     every request pymodbus decoded, for any address, as a line
                  "<time.monotonic()> rx <address, PDU in hex>" (as fault_slave.py records, but
                  without the CRC), flushed at once: what the line carried, for the tests.
--stamp           every register of an FC 03 reply holds how many FC 03 requests its address
                  has had (1, 2, ...): a client can tell which transaction on the line its
                  value came from.
--record-replies  also every reply, as "<time.monotonic()> tx <address, PDU in hex>", taken
                  just before pymodbus writes it (so a reply's row is never later than its
                  end on the line).
"""
import argparse
import asyncio
import time

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.framer import FramerType
from pymodbus.pdu.device import ModbusDeviceIdentification
from pymodbus.server import ModbusSerialServer

# Object id -> value for read device identification (application protocol 6.21): 0..2 basic,
# 3..6 regular, 0x80.. private (extended).
IDENTITY = {
    0x00: "mbgw test vendor",
    0x01: "PEER-17",
    0x02: "3.16.1",
    0x03: "https://example.invalid/peer",
    0x04: "pymodbus RTU peer",
    0x05: "model 17",
    0x06: "mbgw integration tests",
    0x80: "private object 0x80: " + "0123456789" * 6,
}


def device(holding: int = 100) -> ModbusDeviceContext:
    # pymodbus 3.16: block address 1 is PDU address 0
    return ModbusDeviceContext(
        hr=ModbusSequentialDataBlock(1, list(range(holding, holding + 100))),
        ir=ModbusSequentialDataBlock(1, list(range(1000, 1100))),
        co=ModbusSequentialDataBlock(1, [1, 0] * 50),
        di=ModbusSequentialDataBlock(1, [1, 0] * 50))


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("device")
    parser.add_argument("addresses", nargs="*", type=int)
    parser.add_argument("--identity", action="store_true")
    parser.add_argument("--silent-unknown", action="store_true")
    parser.add_argument("--record")
    parser.add_argument("--record-replies", action="store_true")
    parser.add_argument("--stamp", action="store_true")
    parser.add_argument("--holding", type=int, default=100)
    return parser.parse_args()


async def main() -> None:
    args = parse_args()
    addresses = args.addresses or [17]
    context = ModbusServerContext(devices={a: device(args.holding) for a in addresses},
                                  single=False)

    record = open(args.record, "w", buffering=1) if args.record else None
    reads = dict.fromkeys(addresses, 0)

    def watch(sending: bool, pdu):
        # pymodbus's trace_pdu hook: a request dropped here is never executed nor answered.
        if sending:
            if args.stamp and pdu.function_code == 3 and pdu.dev_id in reads:
                pdu.registers = [reads[pdu.dev_id]] * len(pdu.registers)
            if record is not None and args.record_replies:
                frame = bytes((pdu.dev_id, pdu.function_code)) + pdu.encode()
                record.write(f"{time.monotonic()} tx {frame.hex()}\n")
            return pdu
        if record is not None:
            frame = bytes((pdu.dev_id, pdu.function_code)) + pdu.encode()
            record.write(f"{time.monotonic()} rx {frame.hex()}\n")
        if args.stamp and pdu.function_code == 3 and pdu.dev_id in reads:
            reads[pdu.dev_id] += 1
        if not args.silent_unknown or pdu.dev_id == 0 or pdu.dev_id in addresses:
            return pdu
        return None

    server = ModbusSerialServer(
        context, framer=FramerType.RTU, port=args.device, baudrate=19200,
        broadcast_enable=True,
        identity=ModbusDeviceIdentification(info=IDENTITY) if args.identity else None,
        trace_pdu=watch if args.silent_unknown or record is not None or args.stamp else None)
    await server.serve_forever(background=True)
    print("READY", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
