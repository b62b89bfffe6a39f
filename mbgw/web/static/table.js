// ---- Exchange table: read by address, write (admins) --------------------------------------
import { act } from "./actions.js";
import { load } from "./api.js";
import { $, adminControl, clear, el, scrollBox } from "./dom.js";
import { hex4, parseNumber } from "./format.js";

function ascii(value) {
  return [value >> 8, value & 0xff]
    .map((b) => (b >= 0x20 && b < 0x7f ? String.fromCharCode(b) : ".")).join("");
}

export function tablePage(body) {
  const address = el("input", { id: "table-address", value: "0", size: 8 });
  const count = el("input", { id: "table-count", value: "16", size: 5 });
  const view = el("select", { id: "table-view" },
    ...["registers", "bits", "hex", "ascii"].map((v) => el("option", { value: v, text: v })));
  const radix = el("select", { id: "table-radix" },
    el("option", { value: "dec", text: "addresses in decimal" }),
    el("option", { value: "hex", text: "addresses in hex" }));
  const grid = el("div", { id: "table-values" });
  const writeAddress = adminControl(el("input", { id: "table-write-address", size: 8 }));
  const writeValues = adminControl(el("input", { id: "table-write-values", size: 30,
    placeholder: "1, 2, 0x10" }));
  const writeResult = el("span", { id: "table-write-result", class: "result" });
  const writeButton = adminControl(el("button", { type: "button", id: "table-write",
    text: "Write", onclick: () => writeTable() }));
  body.append(
    el("form", { class: "inline", onsubmit: (e) => { e.preventDefault(); page.refresh(); } },
      el("label", {}, "Address ", address), el("label", {}, "Count ", count), view, radix,
      el("button", { type: "submit", text: "Show" })),
    grid,
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
      const start = typeof data.address === "number" ? data.address : at;
      const label = (a) => radix.value === "hex" ? hex4(a) : String(a);
      const format = { registers: String, bits: String, hex: hex4, ascii }[view.value];
      clear(grid).append(scrollBox(el("table", { id: "table-grid" },
        el("thead", {}, el("tr", {}, el("th", { text: "Address" }),
          el("th", { text: view.value }))),
        el("tbody", {}, ...(data.values || []).map((v, i) => el("tr",
          { "data-address": start + i }, el("th", { text: label(start + i) }),
          el("td", { class: "value mono", text: format(v) })))))));
    },
  };
  return page;
}

