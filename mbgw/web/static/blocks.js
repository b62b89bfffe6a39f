// Any block of the status document shown in words and units, so that a block this console
// does not know yet (a new feature's figures) is readable the day it appears.
import { el, factsTable, table } from "./dom.js";
import { figure, show, words } from "./format.js";

const isObject = (v) => v !== null && typeof v === "object" && !Array.isArray(v);
const isEmpty = (v) => v !== null && typeof v === "object" && !Object.keys(v).length;
const isScalar = (v) => !isObject(v) && !(Array.isArray(v) && v.some((x) => x !== null &&
  typeof x === "object"));

// A block: its scalars as a facts table (each row's data-name the dotted path), its lists of
// records as tables, its nested objects as sub-blocks under their own heading.
export function block(path, value, depth = 3) {
  if (isScalar(value)) return factsTable(null, [[path, figure(path, value), words(leaf(path))]]);
  if (Array.isArray(value)) return records(path, value);
  const entries = Object.entries(value);
  if (entries.length > 1 && entries.every(([, v]) => isObject(v) &&
      Object.values(v).every(isScalar))) {         // {"3": {"answered": 5, ...}, ...}: a table
    return records(path, entries.map(([k, v]) => ({ "": k, ...v })));
  }
  const out = el("div", { class: "block", "data-block": path });
  const facts = Object.entries(value).filter(([, v]) => isScalar(v))
    .map(([k, v]) => [`${path}.${k}`, figure(k, v), words(k)]);
  if (facts.length) out.append(factsTable(null, facts));
  for (const [k, v] of Object.entries(value)) {
    if (isScalar(v) || isEmpty(v)) continue;
    out.append(el(`h${Math.min(depth, 6)}`, { text: words(k) }),
      block(`${path}.${k}`, v, depth + 1));
  }
  return out;
}

function leaf(path) { return path.slice(path.lastIndexOf(".") + 1); }

// A list of records as one table: a column per key any of them has.
function records(path, items) {
  const keys = [];
  for (const item of items) {
    for (const k of Object.keys(isObject(item) ? item : {})) if (!keys.includes(k)) keys.push(k);
  }
  return table(null, keys.map(words), items.map((item, i) => el("tr",
    { "data-name": `${path}.${i}` },
    ...keys.map((k) => {
      const v = isObject(item) ? item[k] : undefined;
      return el("td", { class: typeof v === "number" ? "num" : "",
        text: isScalar(v) ? figure(k, v) : show(v) });
    }))));
}

// Every block of status not in shown, each under its heading.
export function otherBlocks(status, shown) {
  return Object.entries(status).filter(([k, v]) => !shown.has(k) && v !== null &&
    typeof v === "object" && !isEmpty(v))
    .flatMap(([k, v]) => [el("h2", { text: words(k) }), block(k, v)]);
}
