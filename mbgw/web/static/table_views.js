// The exchange table's registers as an operator reads them: 16-bit as they are or signed,
// hex, ASCII, and 32-bit integers and floats over two registers (high word first unless
// swapped, high byte first unless swapped); the table's zones and the scenarios' ranges.

// README, "The exchange table".
export const ZONES = [
  { name: "inputs", first: 0x0000, last: 0x07ff },
  { name: "outputs", first: 0x0800, last: 0x0fff },
  { name: "free zone", first: 0x1000, last: 0x7fff },
  { name: "configuration (read-only)", first: 0x8000, last: 0xffff },
];

const swap16 = (v) => ((v & 0xff) << 8) | (v >> 8);

function ascii(value) {
  return [value >> 8, value & 0xff]
    .map((b) => (b >= 0x20 && b < 0x7f ? String.fromCharCode(b) : ".")).join("");
}

function single(view, v) {
  if (view === "int16") return String(v >= 0x8000 ? v - 0x10000 : v);
  if (view === "hex") return "0x" + v.toString(16).toUpperCase().padStart(4, "0");
  if (view === "ascii") return ascii(v);
  return String(v);
}

function double(view, high, low) {
  const buffer = new DataView(new ArrayBuffer(4));
  buffer.setUint16(0, high);
  buffer.setUint16(2, low);
  if (view === "int32") return String(buffer.getInt32(0));
  if (view === "uint32") return String(buffer.getUint32(0));
  const f = buffer.getFloat32(0);
  return Number.isFinite(f) ? String(Number(f.toPrecision(7))) : String(f);
}

// [{address, span, text}]: one cell per register, or per pair for the 32-bit views.
export function typedCells(values, start, view, swap) {
  const word = (v) => (swap.bytes && view !== "bits" ? swap16(v) : v);
  if (!["uint32", "int32", "float32"].includes(view)) {
    return values.map((v, i) => ({ address: start + i, span: 1, text: single(view, word(v)) }));
  }
  const out = [];
  for (let i = 0; i + 1 < values.length; i += 2) {
    const [a, b] = [word(values[i]), word(values[i + 1])];
    out.push({ address: start + i, span: 2, text: swap.words ? double(view, b, a)
      : double(view, a, b) });
  }
  return out;
}

// [{name, first, last}]: the table registers each [[scenario]] of the file writes.
export function ownersOf(tables) {
  const out = [];
  for (const t of tables) {
    const p = t.function === 23 ? "read-" : "";
    const first = t[`${p}table`];
    const quantity = t[`${p}quantity`];
    if (typeof first !== "number" || typeof quantity !== "number") continue;   // bit ranges
    const registers = [1, 2, 5, 15].includes(t.function) ? Math.ceil(quantity / 16) : quantity;
    out.push({ name: t.name, first, last: first + registers - 1 });
  }
  return out;
}
