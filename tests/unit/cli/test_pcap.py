"""The pcap writer of `mbgw trace --pcap` (mbgw.cli.pcap), read back with a parser written here
from the formats' definitions (pcap, Ethernet II, IPv4 RFC 791, IPv6 RFC 8200, TCP RFC 9293),
not with mbgw's code."""
import io
import ipaddress
import struct

import pytest

from mbgw.cli.pcap import PcapWriter

T0 = 1_700_000_000.25


def event(direction: str, tid: int, pdu: str, *, peer: str = "127.0.0.1:40001",
          local: str = "127.0.0.1:502", unit: int = 1, when: float = T0) -> dict:
    data = bytes.fromhex(pdu)
    return {"time": when, "direction": direction, "client": 1, "peer": peer, "local": local,
            "tid": tid, "unit": unit, "function": data[0] if data else 0, "length": len(data),
            "pdu": pdu, "outcome": "", "latency_ms": None}


def internet_checksum(words: bytes) -> int:
    """RFC 1071, the slow obvious way: one's complement of the one's complement sum."""
    total = 0
    for i in range(0, len(words), 2):
        total += (words[i] << 8) + (words[i + 1] if i + 1 < len(words) else 0)
        total = (total & 0xFFFF) + (total >> 16)
    return 0xFFFF - total


def read_pcap(data: bytes) -> tuple[tuple, list[tuple[int, int, bytes]]]:
    header = struct.unpack("<IHHiIII", data[:24])
    records, at = [], 24
    while at < len(data):
        sec, usec, incl, orig = struct.unpack("<IIII", data[at:at + 16])
        assert incl == orig, "the whole frame is captured"
        frame = data[at + 16:at + 16 + incl]
        assert len(frame) == incl, "truncated record"
        records.append((sec, usec, frame))
        at += 16 + incl
    return header, records


def dissect(frame: bytes) -> dict:
    """The fields of one Ethernet / IPv4 or IPv6 / TCP frame."""
    out = {"dst_mac": frame[0:6], "src_mac": frame[6:12],
           "ethertype": struct.unpack("!H", frame[12:14])[0]}
    ip = frame[14:]
    if out["ethertype"] == 0x0800:
        ihl = (ip[0] & 0x0F) * 4
        out.update(ip_version=ip[0] >> 4, ihl=ihl, total_length=struct.unpack("!H", ip[2:4])[0],
                   flags=ip[6] >> 5, fragment_offset=struct.unpack("!H", ip[6:8])[0] & 0x1FFF,
                   ttl=ip[8], protocol=ip[9], ip_checksum=struct.unpack("!H", ip[10:12])[0],
                   ip_header=ip[:ihl], src=ipaddress.IPv4Address(ip[12:16]),
                   dst=ipaddress.IPv4Address(ip[16:20]))
        tcp = ip[ihl:]
        assert out["total_length"] == len(ip)
    else:
        out.update(ip_version=ip[0] >> 4, payload_length=struct.unpack("!H", ip[4:6])[0],
                   next_header=ip[6], hop_limit=ip[7], src=ipaddress.IPv6Address(ip[8:24]),
                   dst=ipaddress.IPv6Address(ip[24:40]))
        tcp = ip[40:]
        assert out["payload_length"] == len(tcp)
    sport, dport, seq, ack, offset, flags = struct.unpack("!HHIIBB", tcp[:14])
    out.update(sport=sport, dport=dport, seq=seq, ack=ack, data_offset=(offset >> 4) * 4,
               tcp_flags=flags, window=struct.unpack("!H", tcp[14:16])[0],
               payload=tcp[(offset >> 4) * 4:])
    return out


def write(*events: dict) -> tuple[tuple, list[tuple[int, int, bytes]], list[bool]]:
    out = io.BytesIO()
    writer = PcapWriter(out)
    written = [writer.write_event(e) for e in events]
    header, records = read_pcap(out.getvalue())
    return header, records, written


def test_global_header_is_a_microsecond_ethernet_pcap_version_2_4():
    header, records, _ = write()
    magic, major, minor, thiszone, sigfigs, snaplen, linktype = header
    assert magic == 0xA1B2C3D4              # little endian, microsecond timestamps
    assert (major, minor) == (2, 4)
    assert (thiszone, sigfigs) == (0, 0)
    assert snaplen >= 65535 - 1             # any frame of ours fits whole
    assert linktype == 1                    # LINKTYPE_ETHERNET
    assert records == []


def test_request_and_reply_are_mbap_segments_between_client_and_gateway():
    request = event("request", 0x1234, "0300100002", unit=17)
    reply = event("reply", 0x1234, "030403e803e9", unit=17, when=T0 + 0.0125)
    _, records, written = write(request, reply)
    assert written == [True, True]
    assert [(s, u) for s, u, _ in records] == [(1_700_000_000, 250_000),
                                                (1_700_000_000, 262_500)]
    q, r = (dissect(f) for _, _, f in records)
    for p in (q, r):
        assert p["ethertype"] == 0x0800
        assert p["ip_version"] == 4 and p["ihl"] == 20 and p["protocol"] == 6
        assert p["fragment_offset"] == 0 and p["ttl"] > 0
        assert p["data_offset"] == 20
        assert p["tcp_flags"] & 0x18 == 0x18          # PSH, ACK
        assert p["tcp_flags"] & 0x07 == 0             # no FIN, SYN, RST
    assert (str(q["src"]), q["sport"], str(q["dst"]), q["dport"]) == \
        ("127.0.0.1", 40001, "127.0.0.1", 502)
    assert (str(r["src"]), r["sport"], str(r["dst"]), r["dport"]) == \
        ("127.0.0.1", 502, "127.0.0.1", 40001)
    # the payload is the Modbus/TCP ADU: MBAP header (tid, protocol 0, length, unit) + PDU
    assert q["payload"] == bytes.fromhex("1234 0000 0006 11 0300100002")
    assert r["payload"] == bytes.fromhex("1234 0000 0007 11 030403e803e9")


@pytest.mark.parametrize("peer, local, src, dst", [
    ("127.0.0.1:40001", "127.0.0.1:502", "127.0.0.1", "127.0.0.1"),
    ("192.168.10.77:65535", "10.0.0.254:1502", "192.168.10.77", "10.0.0.254"),
    # IPv4-mapped IPv6 (a dual-stack listener's view of an IPv4 client): written as IPv4
    ("[::ffff:172.16.1.2]:5020", "[::ffff:172.16.1.1]:502", "172.16.1.2", "172.16.1.1"),
])
def test_ipv4_header_checksum_and_addresses_are_right(peer, local, src, dst):
    _, records, _ = write(event("request", 1, "0300000001", peer=peer, local=local),
                          event("reply", 1, "03020001", peer=peer, local=local),
                          event("request", 2, "10000a0032" + "00" * 101, peer=peer,
                                local=local))       # an odd-length segment
    for _, _, frame in records:
        p = dissect(frame)
        assert p["ip_version"] == 4
        header = p["ip_header"]
        assert internet_checksum(header[:10] + b"\0\0" + header[12:]) == p["ip_checksum"]
        assert internet_checksum(header) == 0                  # the receiver's check
    q, r, _ = (dissect(f) for _, _, f in records)
    assert (str(q["src"]), str(q["dst"]), str(r["src"]), str(r["dst"])) == (src, dst, dst, src)
    assert (q["sport"], r["dport"]) == (int(peer.rsplit(":", 1)[1]),) * 2


def test_sequence_numbers_advance_per_direction_and_acknowledge_the_other():
    events = [event("request", 1, "0300000001"),                       # 12 bytes
              event("request", 2, "0300000002"),                       # 12 bytes, pipelined
              event("reply", 1, "03020001"),                           # 11 bytes
              event("no reply", 3, ""),                                # nothing on the wire
              event("reply", 2, "030400010002"),                       # 13 bytes
              event("request", 4, "0600010005")]                       # 12 bytes
    _, records, written = write(*events)
    assert written == [True, True, True, False, True, True]
    packets = [dissect(f) for _, _, f in records]
    up = [p for p in packets if p["dport"] == 502]
    down = [p for p in packets if p["sport"] == 502]
    assert [len(p["payload"]) for p in up] == [12, 12, 12]
    assert [len(p["payload"]) for p in down] == [11, 13]
    # each direction's stream is contiguous: seq(n+1) = seq(n) + len(n)
    for stream in (up, down):
        for a, b in zip(stream, stream[1:], strict=False):
            assert b["seq"] == (a["seq"] + len(a["payload"])) & 0xFFFFFFFF
    # each segment acknowledges everything the other side had sent before it
    sent = {502: up[0]["seq"], 40001: down[0]["seq"]}     # next seq expected, per sender port
    for p in packets:
        other = 40001 if p["sport"] == 502 else 502
        assert p["ack"] == sent[other]
        sent[p["sport"]] = p["seq"] + len(p["payload"])


def test_two_clients_are_two_tcp_streams():
    a, b = "127.0.0.1:40001", "127.0.0.1:40002"
    _, records, _ = write(event("request", 1, "0300000001", peer=a),
                          event("request", 1, "0300000001", peer=b),
                          event("request", 2, "0300000001", peer=a))
    first_a, first_b, second_a = (dissect(f) for _, _, f in records)
    assert first_a["seq"] == first_b["seq"]          # each stream starts on its own
    assert second_a["seq"] == first_a["seq"] + 12


@pytest.mark.parametrize("peer, local, src, dst", [
    ("[::1]:40001", "[::1]:502", "::1", "::1"),
    ("[fe80::1%eth0]:40001", "[fe80::2%eth0]:502", "fe80::1", "fe80::2"),   # scope dropped
    ("[2001:db8::5]:40001", "127.0.0.1:502", "2001:db8::5", "::ffff:127.0.0.1"),
])
def test_ipv6_peer_is_written_as_ipv6(peer, local, src, dst):
    _, records, _ = write(event("request", 0x0102, "0300000001", peer=peer, local=local),
                          event("reply", 0x0102, "03020001", peer=peer, local=local))
    q, r = (dissect(f) for _, _, f in records)
    for p in (q, r):
        assert p["ethertype"] == 0x86DD
        assert p["ip_version"] == 6 and p["next_header"] == 6 and p["hop_limit"] > 0
    src, dst = ipaddress.IPv6Address(src), ipaddress.IPv6Address(dst)
    assert (q["src"], q["sport"], q["dst"], q["dport"]) == (src, 40001, dst, 502)
    assert (r["src"], r["sport"], r["dst"], r["dport"]) == (dst, 502, src, 40001)
    assert q["payload"] == bytes.fromhex("0102 0000 0006 01 0300000001")
    assert r["ack"] == q["seq"] + len(q["payload"])


def test_events_without_a_frame_write_nothing():
    _, records, written = write(event("no reply", 9, ""),
                                {"direction": "something else", "time": T0})
    assert written == [False, False] and records == []


def test_a_monitor_lines_pair_goes_in_between_the_bus_ends_with_one_tid() -> None:
    heard = {"mode": "monitor", "time": T0, "tid": None, "unit": None, "peer": None,
             "local": None, "address": 7}
    crc_error = {**heard, "direction": "ignored", "pdu": "", "address": 7}
    _, records, written = write({**heard, "direction": "request", "pdu": "0300640002"},
                                {**heard, "direction": "reply", "pdu": "0304000b0016"},
                                crc_error)
    assert written == [True, True, False]
    request, reply = (dissect(frame) for _, _, frame in records)
    assert (str(request["src"]), request["sport"], str(request["dst"]), request["dport"]) == \
        ("127.0.77.1", 40000, "127.0.77.2", 502)
    assert (str(reply["src"]), reply["dport"]) == ("127.0.77.2", 40000)
    assert request["payload"] == bytes.fromhex("0001 0000 0006 07 0300640002")
    assert reply["payload"] == bytes.fromhex("0001 0000 0007 07 0304000b0016")
