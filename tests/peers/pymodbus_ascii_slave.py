"""A real ASCII serial slave that is not our code: pymodbus's ASCII server on a pty.

usage: pymodbus_ascii_slave.py DEVICE [ADDRESS...]          (default address 17)

The same data as pymodbus_slave.py (holding register n holds 100 + n, input register n holds
1000 + n, coils and discrete inputs alternate 1, 0), framed as Modbus ASCII (FramerType.ASCII).
The pty runs 8N1: ptys force CS8 and no parity (notes/libmodbus.md 3.7-3.8).  Prints READY
when listening.
"""
import argparse
import asyncio
import sys
from pathlib import Path

from pymodbus.datastore import ModbusServerContext
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer

sys.path.insert(0, str(Path(__file__).parent))
from pymodbus_slave import device  # the same datastore as the RTU peer


async def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("device")
    parser.add_argument("addresses", nargs="*", type=int)
    args = parser.parse_args()
    addresses = args.addresses or [17]
    context = ModbusServerContext(devices={a: device() for a in addresses}, single=False)
    server = ModbusSerialServer(context, framer=FramerType.ASCII, port=args.device,
                                baudrate=19200, bytesize=8, parity="N", stopbits=1)
    await server.serve_forever(background=True)
    print("READY", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
