// ---- The [[route]] tables edited on the Lines page: add, change, delete, applied together --
import { act, confirmed } from "./actions.js";
import { api } from "./api.js";
import { adminControl, clear, el, scrollBox } from "./dom.js";

const TCP_FACE = "";                // a route without `from`: the Modbus TCP face's
const KEPT = ["tls", "fingerprint"];    // keys the editor shows no field for, kept as they are

// {ttl = 500, serve-stale = 0} -> "ttl=500,serve-stale=0"; false -> "off"; none -> ""
function cacheText(cache) {
  if (cache === false) return "off";
  if (!cache || typeof cache !== "object") return cache === undefined ? "" : String(cache);
  return Object.entries(cache).map(([k, v]) => `${k}=${v}`).join(",");
}

// The reverse: "" -> undefined (the line's), "off" -> false, "ttl=500" -> {ttl: 500}
function cacheValue(text) {
  const t = text.trim();
  if (!t) return undefined;
  if (t === "off" || t === "false") return false;
  const table = {};
  for (const part of t.split(",").map((p) => p.trim()).filter(Boolean)) {
    const [name, value] = part.split("=").map((w) => w.trim());
    table[name] = /^\d+$/.test(value || "") ? Number(value) : value;
  }
  return table;
}

const option = (value, text, selected) => el("option", { value, text, selected });
const tagged = (node, key) => { node.dataset.key = key; return adminControl(node); };

// One route's row.  lines: {faces: [names], targets: [names]} of the running daemon.
function routeRow(route, lines, renumber) {
  const from = route.from ?? TCP_FACE;
  const faces = [TCP_FACE, ...lines.faces.filter((f) => f !== from)];
  if (from !== TCP_FACE) faces.splice(1, 0, from);
  const fromSelect = tagged(el("select", {}, ...faces.map((f) =>
    option(f, f === TCP_FACE ? "Modbus TCP" : `line ${f}`, f === from))), "from");
  const target = route.table ? "table" : route.server !== undefined ? "server"
    : `line:${route.line ?? ""}`;
  const targets = lines.targets.map((n) => `line:${n}`);
  if (target.startsWith("line:") && !targets.includes(target)) targets.unshift(target);
  const targetSelect = tagged(el("select", {},
    ...targets.map((t) => option(t, `line ${t.slice(5)}`, t === target)),
    option("table", "the exchange table", target === "table"),
    option("server", "a Modbus TCP server", target === "server")), "target");
  const server = tagged(el("input", { size: 16, placeholder: "IP[:PORT]",
    value: route.server ?? "" }), "server");
  server.hidden = target !== "server";
  targetSelect.addEventListener("change", () => { server.hidden = targetSelect.value !== "server"; });
  const rewriteKind = route.address !== undefined ? "address"
    : route.offset !== undefined ? "offset" : "";
  const rewrite = tagged(el("select", {}, option("", "none", rewriteKind === ""),
    option("offset", "offset", rewriteKind === "offset"),
    option("address", "fixed address", rewriteKind === "address")), "rewrite");
  const amount = tagged(el("input", { size: 5, type: "number",
    value: route.address ?? route.offset ?? "" }), "amount");
  amount.hidden = rewriteKind === "";
  rewrite.addEventListener("change", () => { amount.hidden = rewrite.value === ""; });
  const tr = el("tr", { class: "route" }, el("td", { class: "num index" }),
    el("td", {}, fromSelect),
    el("td", {}, tagged(el("input", { size: 10, value: route.units ?? "",
      placeholder: "1-31,40" }), "units")),
    el("td", {}, targetSelect, " ", server),
    el("td", {}, rewrite, " ", amount),
    el("td", {}, tagged(el("input", { size: 14, value: cacheText(route.cache),
      placeholder: "the line's", title: "empty: the line's; off; ttl=MS,serve-stale=MS" }),
    "cache")),
    el("td", { class: "actions" }, adminControl(el("button", { type: "button",
      class: "delete", text: "Delete", onclick: () => { tr.remove(); renumber(); } }))));
  tr.kept = Object.fromEntries(KEPT.filter((k) => k in route).map((k) => [k, route[k]]));
  return tr;
}

// A row as its [[route]] table's keys.
function tableOf(tr) {
  const get = (key) => tr.querySelector(`[data-key="${key}"]`);
  const route = {};
  if (get("from").value !== TCP_FACE) route.from = get("from").value;
  route.units = get("units").value.replace(/\s+/g, "");
  const target = get("target").value;
  if (target === "table") route.table = true;
  else if (target === "server") route.server = get("server").value.trim();
  else route.line = target.slice(5);
  const amount = get("amount").value.trim();
  const rewrite = get("rewrite").value;
  if (rewrite && amount !== "") route[rewrite] = Number(amount);
  const cache = cacheValue(get("cache").value);
  if (cache !== undefined) route.cache = cache;
  return { ...route, ...tr.kept };
}

// The editor: {element, reload()}; lines() -> {faces, targets}: the running daemon's lines
// by role (reload() once they are known: the choices of a row are made with it).
export function routeEditor(lines) {
  const tbody = el("tbody");
  const out = el("p", { id: "routes-result", class: "result" });
  const renumber = () => [...tbody.children].forEach((tr, i) => {
    tr.firstChild.textContent = String(i + 1);
  });
  const editor = el("section", { id: "route-editor" },
    el("h2", { text: "The file's routes" }),
    el("p", { class: "hint", text: "Which units of a face go where: change, add or delete " +
      "routes, then apply them together (checked as mbgw check-config does, one reload). " +
      "Without routes the implicit ones above apply." }),
    scrollBox(el("table", { id: "routes-edit" }, el("thead", {}, el("tr", {},
      ...["Route", "From", "Units", "Target", "Rewrite", "Cache", ""].map((h) =>
        el("th", { text: h })))), tbody)),
    el("div", { class: "controls" },
      adminControl(el("button", { type: "button", id: "routes-add", text: "Add a route",
        onclick: () => { tbody.append(routeRow({}, lines(), renumber)); renumber(); } })),
      adminControl(el("button", { type: "button", id: "routes-apply",
        text: "Apply the routes", onclick: apply }))),
    out);
  editor.hidden = true;              // until reload(): a mode without lines has no routes

  async function apply() {
    for (const bad of tbody.querySelectorAll(".invalid")) bad.classList.remove("invalid");
    const routes = [...tbody.children].map(tableOf);
    if (!routes.length && !confirmed("Delete every route (the implicit ones then apply)?")) {
      return;
    }
    const result = await act(out, "POST", "/api/routes", { routes },
      (data) => (data.reload && data.reload.message) || "applied");
    if (result.ok) { reload(); return; }
    const field = /^route (\d+)\.([a-z-]+)$/.exec(result.data.field || "");
    if (field) {
      const key = { line: "target", table: "target", server: "server", offset: "amount",
        address: "amount" }[field[2]] || field[2];
      const row = tbody.children[Number(field[1]) - 1];
      const input = row && row.querySelector(`[data-key="${key}"]`);
      if (input) input.classList.add("invalid");
    }
  }

  async function reload() {
    const result = await api("GET", "/api/routes");
    editor.hidden = result.status === 404;     // settings from the command line: no file
    if (!result.ok) {
      out.className = "result error";
      out.textContent = result.data.error;
      return;
    }
    const data = result.data;
    clear(tbody).append(...(data.routes || []).map((r) => routeRow(r, lines(), renumber)));
    renumber();
  }
  return { element: editor, reload };
}
