"""pymodbus's Modbus TCP server, a reference of the table row (bench/table.py); not part of mbgw.

usage: pymodbus_server.py PORT

Serves 65536 holding and 65536 input registers (all zero) to any unit id on 127.0.0.1:PORT,
with the venv's pinned pymodbus: asyncio, the ModbusTcpServer that StartAsyncTcpServer runs
(started in the background here, so that READY is printed once it listens).
"""
import asyncio
import logging
import sys

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.server import ModbusTcpServer

REGISTERS = 65536


def context() -> ModbusServerContext:
    # pymodbus 3.16: block address 1 is PDU address 0; a device context that is not in a
    # dict answers every unit id
    return ModbusServerContext(devices=ModbusDeviceContext(
        hr=ModbusSequentialDataBlock(1, [0] * REGISTERS),
        ir=ModbusSequentialDataBlock(1, [0] * REGISTERS)))


async def main(port: int) -> None:
    logging.getLogger("pymodbus").setLevel(logging.ERROR)    # no deprecation chatter
    server = ModbusTcpServer(context(), address=("127.0.0.1", port))
    await server.serve_forever(background=True)
    print("READY", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1])))
