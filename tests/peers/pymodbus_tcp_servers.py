"""Remote Modbus TCP servers that are not our code: pymodbus's, one per address, all on one
port (the whole of 127/8 is loopback, so master mode's per-address IPs can be tested for real).

usage: pymodbus_tcp_servers.py PORT HOST... [--silent HOST...] [--slow-ms MS]
                                [--tls CERT KEY CA]     (all HOSTs are IPv4 literals)
Every server has unit ids UNITS (0 is a broadcast, executed on each of them).  The holding
registers of unit u on host a.b.c.d: 0 -> c, 1 -> d, 2 -> u, 3..9 -> 103..109 (writable);
reading from 10 on gets exception 02 (illegal data address).

--silent HOST   that server accepts connections but never answers.
--slow-ms MS    the answer to a read from holding register 9 is sent MS ms late (the whole
                process stalls meanwhile; requests that came in the meantime are served after).
--tls CERT KEY CA   Modbus/TCP Security: pymodbus's TLS server (TLS 1.2/1.3), with the
                certificate CERT and its KEY, the client's certificate required and checked
                against CA.

Prints READY when every server listens, then "CONNECT HOST" / "DISCONNECT HOST" for each
connection made and lost.
"""
import argparse
import asyncio
import ipaddress
import logging
import ssl
import time

from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.server import ModbusTcpServer, ModbusTlsServer

UNITS = (*range(1, 41), 0xFF)
SIZE = 10
SLOW_REGISTER = 9


def device(host: ipaddress.IPv4Address, unit: int) -> ModbusDeviceContext:
    c, d = host.packed[2:]
    # pymodbus 3.16: block address 1 is PDU address 0
    return ModbusDeviceContext(hr=ModbusSequentialDataBlock(
        1, [c, d, unit, *range(103, 103 + SIZE - 3)]))


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("hosts", nargs="+", type=ipaddress.IPv4Address)
    parser.add_argument("--silent", nargs="*", default=[], type=ipaddress.IPv4Address)
    parser.add_argument("--slow-ms", type=int, default=0)
    parser.add_argument("--tls", nargs=3, metavar=("CERT", "KEY", "CA"))
    return parser.parse_args()


def tracers(host: str, silent: bool, slow_s: float):
    def on_connect(connected: bool) -> None:
        print(f"{'CONNECT' if connected else 'DISCONNECT'} {host}", flush=True)

    slow_reply = False

    def on_pdu(sending: bool, pdu):
        nonlocal slow_reply
        if sending:
            if slow_reply:
                slow_reply = False
                time.sleep(slow_s)
            return pdu
        if silent:
            return None          # a request dropped here is never executed nor answered
        slow_reply = bool(slow_s) and pdu.function_code == 3 and pdu.address == SLOW_REGISTER
        return pdu

    return on_connect, on_pdu


def tls_context(cert: str, key: str, ca: str) -> ssl.SSLContext:
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.verify_mode = ssl.CERT_REQUIRED
    context.load_cert_chain(cert, key)
    context.load_verify_locations(ca)
    return context


async def main() -> None:
    args = parse_args()
    logging.getLogger("pymodbus").setLevel(logging.ERROR)    # no deprecation chatter
    servers = []
    for host in args.hosts:
        context = ModbusServerContext(devices={u: device(host, u) for u in UNITS})
        on_connect, on_pdu = tracers(str(host), host in args.silent, args.slow_ms / 1000)
        if args.tls:
            server = ModbusTlsServer(context, address=(str(host), args.port),
                                     sslctx=tls_context(*args.tls), broadcast_enable=True,
                                     trace_connect=on_connect, trace_pdu=on_pdu)
        else:
            server = ModbusTcpServer(context, address=(str(host), args.port),
                                     broadcast_enable=True, trace_connect=on_connect,
                                     trace_pdu=on_pdu)
        await server.serve_forever(background=True)
        servers.append(server)
    print("READY", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
