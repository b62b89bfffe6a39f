// Values as an operator reads them: dates in ISO (as the CLI prints them) and "x ago",
// durations, latencies in ms, and a status key's words and unit.

export function show(value) {
  if (value === null || value === undefined) return "—";
  if (Array.isArray(value)) return value.map(show).join(", ");
  if (typeof value === "object") return JSON.stringify(value);
  return String(value);
}

const pad = (n, w) => String(n).padStart(w || 2, "0");

// "2026-11-27 17:40:40": a Unix time in the browser's time zone, as `mbgw status` writes it.
export function isoTime(unix) {
  if (typeof unix !== "number") return "—";
  const d = new Date(unix * 1000);
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ` +
         `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
}

// "2026-11-27 17:40:40 (00:03:12 ago)"
export function when(unix) {
  return typeof unix === "number" ? `${isoTime(unix)} (${ago(unix)})` : "—";
}

export function clock(unix) {
  const d = new Date(unix * 1000);
  return `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.` +
         pad(d.getMilliseconds(), 3);
}

export function ago(unix) {
  if (typeof unix !== "number") return "—";
  return duration(Math.max(0, Date.now() / 1000 - unix)) + " ago";
}

export function duration(seconds) {
  if (typeof seconds !== "number") return "—";
  const s = Math.floor(seconds);
  const days = Math.floor(s / 86400);
  const hms = [Math.floor(s / 3600) % 24, Math.floor(s / 60) % 60, s % 60]
    .map((n) => String(n).padStart(2, "0")).join(":");
  return days ? `${days} d ${hms}` : hms;
}

// "12.3 ms", "0.42 ms", "1250 ms": three significant figures at most, none for whole ms.
export function ms(value) {
  if (typeof value !== "number") return "—";
  const digits = value >= 100 ? 0 : value >= 10 ? 1 : 2;
  return `${value.toFixed(digits)} ms`;
}

// "12", "0x1F" or "1fh": a number, or NaN.
export function parseNumber(text) {
  const t = String(text).trim().toLowerCase();
  if (/^0x[0-9a-f]+$/.test(t)) return parseInt(t.slice(2), 16);
  if (/^[0-9a-f]+h$/.test(t)) return parseInt(t.slice(0, -1), 16);
  if (/^[0-9]+$/.test(t)) return parseInt(t, 10);
  return NaN;
}

export function hex4(n) { return "0x" + n.toString(16).toUpperCase().padStart(4, "0"); }

export function listOf(data, key) {
  if (Array.isArray(data)) return data;
  return (data && Array.isArray(data[key])) ? data[key] : [];
}

// A status key's unit, by the suffix the status document gives it (docs/console.md).
const UNITS = [["_ms", "ms"], ["_us", "µs"], ["_s", "s"], ["_pct", "%"]];
const TIME_KEY = /(^|_)(since|started|time|at)$|^last_(success|activity|answer|save|change)/;

// "crc_errors" -> "CRC errors", "latency_p99_ms" -> "latency p99": a key in words.
export function words(key) {
  let text = String(key);
  for (const [suffix] of UNITS) if (text.endsWith(suffix)) text = text.slice(0, -suffix.length);
  text = text.replace(/[_-]/g, " ").replace(/\b(crc|tcp|tls|rtu|ascii|pdu|id|ip|mqtt|p\d+)\b/gi,
    (w) => (/^p\d+$/i.test(w) ? w.toLowerCase() : w.toUpperCase()));
  return text.charAt(0).toUpperCase() + text.slice(1);
}

// A figure with its unit: times as ISO and "ago", ms with sensible decimals.
export function figure(key, value) {
  if (typeof value !== "number") return show(value);
  if (TIME_KEY.test(key) && value > 1e9) return when(value);
  if (key.endsWith("_ms")) return ms(value);
  for (const [suffix, unit] of UNITS) {
    if (key.endsWith(suffix)) {
      return `${Number.isInteger(value) ? value : value.toFixed(1)} ${unit}`;
    }
  }
  return Number.isInteger(value) ? String(value) : value.toFixed(2);
}
