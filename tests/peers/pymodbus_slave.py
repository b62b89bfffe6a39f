"""A real serial slave that is not our code: pymodbus's RTU server on a pty.

usage: pymodbus_slave.py DEVICE [ADDRESS...]   (default address 17)
Holding registers 0..99 hold 100..199, input registers 0..99 hold 1000..1099,
coils and discrete inputs alternate 1, 0 from address 0.  Prints READY when listening.
"""
import asyncio
import sys

from pymodbus.datastore import (ModbusDeviceContext, ModbusSequentialDataBlock,
                                ModbusServerContext)
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer


def device() -> ModbusDeviceContext:
    # pymodbus 3.16: block address 1 is PDU address 0
    return ModbusDeviceContext(
        hr=ModbusSequentialDataBlock(1, list(range(100, 200))),
        ir=ModbusSequentialDataBlock(1, list(range(1000, 1100))),
        co=ModbusSequentialDataBlock(1, [1, 0] * 50),
        di=ModbusSequentialDataBlock(1, [1, 0] * 50))


async def main() -> None:
    path = sys.argv[1]
    addresses = [int(a) for a in sys.argv[2:]] or [17]
    context = ModbusServerContext(devices={a: device() for a in addresses}, single=False)
    server = ModbusSerialServer(context, framer=FramerType.RTU, port=path, baudrate=19200,
                                broadcast_enable=True)
    await server.serve_forever(background=True)
    print("READY", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
