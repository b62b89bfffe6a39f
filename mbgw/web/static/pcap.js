// The pcap of the trace events the Traffic page showed, made in the browser as mbgw/cli/pcap.py
// makes `mbgw trace --pcap`: each request and reply one TCP segment between the client's
// address and the gateway's, in synthetic Ethernet and IPv4/IPv6 headers, with per-direction
// sequence numbers so that Wireshark reassembles the Modbus/TCP stream.

const PCAP_ETHER_MACS = [2, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0, 2];
const PCAP_TCP_PSH_ACK = 0x18;

// "1.2.3.4:502" or "[::1]:502": {bytes: 4 or 16 numbers, port}; null when it is neither.
function pcapAddress(text) {
  const at = String(text).lastIndexOf(":");
  if (at < 0) return null;
  const host = text.slice(0, at).replace(/^\[|\]$/g, "").split("%")[0];
  const port = parseInt(text.slice(at + 1), 10);
  const mapped = /^::ffff:(\d+\.\d+\.\d+\.\d+)$/i.exec(host);
  const v4 = /^\d+\.\d+\.\d+\.\d+$/.test(host) ? host : mapped ? mapped[1] : null;
  if (v4) return { bytes: v4.split(".").map(Number), port };
  const halves = host.split("::");
  if (halves.length > 2) return null;
  const words = (part) => (part ? part.split(":").map((w) => parseInt(w, 16)) : []);
  const head = words(halves[0]);
  const tail = halves.length === 2 ? words(halves[1]) : [];
  const all = [...head, ...new Array(8 - head.length - tail.length).fill(0), ...tail];
  if (all.length !== 8 || all.some(Number.isNaN)) return null;
  return { bytes: all.flatMap((w) => [w >> 8, w & 0xff]), port };
}

function pcapChecksum(bytes) {
  let total = 0;
  for (let i = 0; i < bytes.length; i += 2) total += (bytes[i] << 8) + (bytes[i + 1] || 0);
  while (total > 0xffff) total = (total & 0xffff) + (total >>> 16);
  return ~total & 0xffff;
}

function be(value, size) {
  const out = [];
  for (let i = size - 1; i >= 0; i--) out.push(Math.floor(value / 2 ** (8 * i)) & 0xff);
  return out;
}

function le(value, size) { return be(value, size).reverse(); }

function hexBytes(hex) {
  const out = [];
  for (let i = 0; i + 1 < hex.length; i += 2) out.push(parseInt(hex.slice(i, i + 2), 16));
  return out;
}

// A Blob of the pcap file; events that carried nothing over TCP are left out.
export function pcapOf(events) {
  const parts = [new Uint8Array([...le(0xa1b2c3d4, 4), ...le(2, 2), ...le(4, 2), ...le(0, 4),
    ...le(0, 4), ...le(65535, 4), ...le(1, 4)])];
  const seq = new Map();
  for (const event of events) {
    if (!["request", "reply"].includes(event.direction) || !event.peer || !event.local) continue;
    const client = pcapAddress(event.peer);
    const server = pcapAddress(event.local);
    if (!client || !server) continue;
    const pdu = hexBytes(event.pdu || "");
    const payload = [...be(event.tid || 0, 2), 0, 0, ...be(pdu.length + 1, 2), event.unit & 0xff,
      ...pdu];
    const [src, dst] = event.direction === "request" ? [client, server] : [server, client];
    const flow = `${src.bytes}:${src.port}>${dst.bytes}:${dst.port}`;
    const back = `${dst.bytes}:${dst.port}>${src.bytes}:${src.port}`;
    const s = seq.has(flow) ? seq.get(flow) : 1;
    seq.set(flow, (s + payload.length) % 2 ** 32);
    const ack = seq.has(back) ? seq.get(back) : 1;
    const tcp = [...be(src.port, 2), ...be(dst.port, 2), ...be(s, 4), ...be(ack, 4), 5 << 4,
      PCAP_TCP_PSH_ACK, ...be(65535, 2), 0, 0, 0, 0, ...payload];
    let frame;
    if (src.bytes.length === 4 && dst.bytes.length === 4) {
      const ip = [0x45, 0, ...be(20 + tcp.length, 2), 0, 0, 0x40, 0, 64, 6, 0, 0,
        ...src.bytes, ...dst.bytes];
      const sum = pcapChecksum(ip);
      ip[10] = sum >> 8;
      ip[11] = sum & 0xff;
      frame = [...PCAP_ETHER_MACS, 0x08, 0x00, ...ip, ...tcp];
    } else {
      const v6 = (a) => (a.bytes.length === 16 ? a.bytes
        : [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xff, 0xff, ...a.bytes]);
      const ip = [...be(6 << 28 >>> 0, 4), ...be(tcp.length, 2), 6, 64, ...v6(src), ...v6(dst)];
      frame = [...PCAP_ETHER_MACS, 0x86, 0xdd, ...ip, ...tcp];
    }
    const when = typeof event.time === "number" ? event.time : Date.now() / 1000;
    const seconds = Math.floor(when);
    parts.push(new Uint8Array([...le(seconds, 4), ...le(Math.floor((when - seconds) * 1e6), 4),
      ...le(frame.length, 4), ...le(frame.length, 4), ...frame]));
  }
  return new Blob(parts, { type: "application/vnd.tcpdump.pcap" });
}
