// ---- Exchange table: read by address, write (admins) --------------------------------------
import { act } from "./actions.js";
import { api, load } from "./api.js";
import { $, adminControl, clear, el, scrollBox } from "./dom.js";
import { hex4, listOf, parseNumber } from "./format.js";
import { ZONES, ownersOf, typedCells } from "./table_views.js";

function ascii(value) {
  return [value >> 8, value & 0xff]
    .map((b) => (b >= 0x20 && b < 0x7f ? String.fromCharCode(b) : ".")).join("");
}

export function tablePage(body) {
  const address = el("input", { id: "table-address", value: "0", size: 8 });
  const count = el("input", { id: "table-count", value: "64", size: 5 });
  const view = el("select", { id: "table-view" },
    ...["registers", "int16", "hex", "ascii", "bits", "uint32", "int32", "float32"]
      .map((v) => el("option", { value: v, text: v })));
  const radix = el("select", { id: "table-radix" },
    el("option", { value: "dec", text: "addresses in decimal" }),
    el("option", { value: "hex", text: "addresses in hex" }));
  const swapWords = el("input", { type: "checkbox", id: "table-swap-words" });
  const swapBytes = el("input", { type: "checkbox", id: "table-swap-bytes" });
  const grid = el("div", { id: "table-values" });
  const legend = el("ul", { id: "table-owners" });
  const writeAddress = adminControl(el("input", { id: "table-write-address", size: 8 }));
  const writeValues = adminControl(el("input", { id: "table-write-values", size: 30,
    placeholder: "1, 2, 0x10" }));
  const writeResult = el("span", { id: "table-write-result", class: "result" });
  const writeButton = adminControl(el("button", { type: "button", id: "table-write",
    text: "Write", onclick: () => writeTable() }));
  const again = () => page.refresh();
  for (const control of [view, radix, swapWords, swapBytes]) {
    control.addEventListener("change", again);
  }
  body.append(
    el("form", { class: "inline", onsubmit: (e) => { e.preventDefault(); page.refresh(); } },
      el("label", {}, "Address ", address), el("label", {}, "Count ", count), view, radix,
      el("label", {}, swapWords, " swap words"), el("label", {}, swapBytes, " swap bytes"),
      el("button", { type: "submit", text: "Show" })),
    grid, legend,
    el("h2", { text: "Write registers" }),
    el("form", { class: "inline", onsubmit: (e) => { e.preventDefault(); writeTable(); } },
      el("label", {}, "Address ", writeAddress), el("label", {}, "Values ", writeValues),
      writeButton, writeResult));

  async function writeTable() {
    const at = parseNumber(writeAddress.value);
    const values = writeValues.value.split(/[\s,]+/).filter(Boolean).map(parseNumber);
    if (Number.isNaN(at) || !values.length || values.some(Number.isNaN)) {
      writeResult.className = "result error";
      writeResult.textContent = "an address and values, in decimal or 0x hex";
      return;
    }
    await act(writeResult, "POST", "/api/table", { address: at, values },
      `written ${values.length} from ${hex4(at)}`);
    page.refresh();
  }

  const page = {
    async refresh() {
      const at = parseNumber(address.value);
      const n = parseNumber(count.value);
      if (Number.isNaN(at) || Number.isNaN(n)) {
        $("page-error").textContent = "address and count: decimal, or hex as 0x1F";
        return;
      }
      const bits = view.value === "bits";
      const data = await load(`/api/table?address=${at}&count=${n}&bits=${bits ? 1 : 0}`);
      if (!data) return;
      const file = bits ? null : await api("GET", "/api/scenarios/config");
      const owners = ownersOf(listOf(file && file.ok ? file.data : null, "scenarios"));
      const start = typeof data.address === "number" ? data.address : at;
      const label = (a) => radix.value === "hex" ? hex4(a) : String(a);
      const cells = typedCells(data.values || [], start, view.value,
        { words: swapWords.checked, bytes: swapBytes.checked });
      const rows = [];
      let zone = null;
      for (let row = start - (start % 16); row < start + (data.values || []).length; row += 16) {
        const here = bits ? null : ZONES.find((z) => row >= z.first && row <= z.last);
        if (here && here !== zone) {
          zone = here;
          rows.push(el("tr", { class: "zone" }, el("th", { colspan: 17,
            text: `${here.name} ${hex4(here.first)}-${hex4(here.last)}` })));
        }
        const tds = [];
        for (const cell of cells.filter((c) => c.address >= row && c.address < row + 16)) {
          const owner = bits ? null : owners.find((o) => cell.address >= o.first &&
            cell.address <= o.last);
          tds.push(el("td", { class: `value mono${owner ? " owned" : ""}`, colspan: cell.span,
            "data-address": cell.address, title: `${label(cell.address)}` +
            (owner ? `: scenario ${owner.name}` : ""), text: cell.text }));
        }
        const lead = Math.max(0, start - row);        // the cells before the first shown
        rows.push(el("tr", { "data-address": row }, el("th", { text: label(row) }),
          ...(lead ? [el("td", { colspan: lead })] : []), ...tds));
      }
      clear(grid).append(scrollBox(el("table", { id: "table-grid", class: "grid" },
        el("thead", {}, el("tr", {}, el("th", { text: "Address" }),
          ...Array.from({ length: 16 }, (_, i) => el("th", { text: `+${i.toString(radix.value
            === "hex" ? 16 : 10).toUpperCase()}` })))),
        el("tbody", {}, ...rows))));
      const shown = owners.filter((o) => o.last >= start && o.first < start + cells.length * 2);
      clear(legend).append(...shown.map((o) => el("li", { class: "owned",
        text: `scenario ${o.name}: ${label(o.first)}-${label(o.last)}` })));
    },
  };
  return page;
}
