"""A Modbus/UDP device that is not our code: pymodbus's UDP server on 127.0.0.1.

usage: pymodbus_udp_server.py PORT [ADDRESS...]            (default address 1)
Holding registers 0..99 hold 100..199 (as pymodbus_slave.py's).  Prints READY when listening.
"""
import argparse
import asyncio

from pymodbus.datastore import ModbusServerContext
from pymodbus.framer import FramerType
from pymodbus.server import ModbusUdpServer
from pymodbus_slave import device


async def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("addresses", nargs="*", type=int)
    args = parser.parse_args()
    context = ModbusServerContext(devices={a: device() for a in args.addresses or [1]},
                                  single=False)
    server = ModbusUdpServer(context, framer=FramerType.SOCKET, address=("127.0.0.1", args.port))
    await server.serve_forever(background=True)
    print("READY", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
