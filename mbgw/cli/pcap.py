"""Writes traced Modbus/TCP traffic as a pcap file that Wireshark and tshark decode.

Each request and reply becomes one TCP segment between the client's address and the
gateway's, inside synthetic Ethernet and IPv4/IPv6 headers, with per-direction sequence
numbers so that the TCP stream reassembles.  What a monitor line heard (RTU on a bus mbgw
only listens to) goes in as Modbus/TCP too, between two made-up ends (MONITOR_MASTER, the
bus's master; MONITOR_BUS, its slaves): the unit is the serial address, and each request
and its reply share a transaction id numbered here."""
import ipaddress
import struct

from mbgw.line import native

LINKTYPE_ETHERNET = 1
_ETHER_IPV4 = b"\x02\x00\x00\x00\x00\x01" + b"\x02\x00\x00\x00\x00\x02" + b"\x08\x00"
_ETHER_IPV6 = b"\x02\x00\x00\x00\x00\x01" + b"\x02\x00\x00\x00\x00\x02" + b"\x86\xdd"
_TCP_PSH_ACK = 0x18
MONITOR_MASTER = "127.0.77.1:40000"
MONITOR_BUS = "127.0.77.2:502"


def _split(address: str) -> tuple[ipaddress.IPv4Address | ipaddress.IPv6Address, int]:
    host, _, port = address.rpartition(":")
    host = host.strip("[]").split("%", 1)[0]
    ip = ipaddress.ip_address(host)
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped:
        ip = ip.ipv4_mapped
    return ip, int(port)


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\0"
    total = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


class PcapWriter:
    def __init__(self, stream) -> None:
        self._out = stream
        self._seq: dict[tuple, int] = {}
        self._monitor_tid = 0
        stream.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, LINKTYPE_ETHERNET))

    def write_event(self, event: dict) -> bool:
        """One traced request or reply; False for events that carried nothing."""
        if event.get("direction") not in ("request", "reply"):
            return False
        if event.get("mode") == "monitor":
            return self._heard(event)
        if event.get("peer") is None:
            return False          # nothing went over TCP (master mode's table slave)
        payload = native.frame(event["tid"], event["unit"], bytes.fromhex(event["pdu"]))
        client, server = _split(event["peer"]), _split(event["local"])
        if event["direction"] == "request":
            src, dst = client, server
        else:
            src, dst = server, client
        self._packet(event["time"], src, dst, payload)
        return True

    def _heard(self, event: dict) -> bool:
        """A frame heard on a monitor line, between the bus's made-up ends."""
        if event["direction"] == "request":
            self._monitor_tid = (self._monitor_tid + 1) & 0xFFFF
            src, dst = _split(MONITOR_MASTER), _split(MONITOR_BUS)
        else:
            src, dst = _split(MONITOR_BUS), _split(MONITOR_MASTER)
        payload = native.frame(self._monitor_tid, event["address"], bytes.fromhex(event["pdu"]))
        self._packet(event["time"], src, dst, payload)
        return True

    def _packet(self, when: float, src, dst, payload: bytes) -> None:
        flow = (src, dst)
        seq = self._seq.get(flow, 1)
        self._seq[flow] = (seq + len(payload)) & 0xFFFFFFFF
        ack = self._seq.get((dst, src), 1)
        tcp = struct.pack("!HHIIBBHHH", src[1], dst[1], seq, ack, 5 << 4, _TCP_PSH_ACK,
                          65535, 0, 0) + payload
        if src[0].version == 4 and dst[0].version == 4:
            ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(tcp), 0, 0x4000, 64, 6, 0,
                             src[0].packed, dst[0].packed)
            ip = ip[:10] + struct.pack("!H", _checksum(ip)) + ip[12:]
            frame = _ETHER_IPV4 + ip + tcp
        else:
            s, d = (a[0] if a[0].version == 6 else ipaddress.IPv6Address(
                f"::ffff:{a[0]}") for a in (src, dst))
            ip = struct.pack("!IHBB16s16s", 6 << 28, len(tcp), 6, 64, s.packed, d.packed)
            frame = _ETHER_IPV6 + ip + tcp
        seconds = int(when)
        self._out.write(struct.pack("<IIII", seconds, int((when - seconds) * 1e6),
                                    len(frame), len(frame)))
        self._out.write(frame)
        self._out.flush()
