// The scenarios toolbox (VPGate 6.2/6.3): a [[scenario]] table created, changed, duplicated
// or tested in a form; several deleted at once.  Every change is checked as `mbgw config
// scenario add` checks it, written at once and applied by one reload.
import { act, confirmed } from "./actions.js";
import { adminControl, el } from "./dom.js";
import { show } from "./format.js";

const FUNCTIONS = [[1, "1 read coils"], [2, "2 read discrete inputs"],
  [3, "3 read holding registers"], [4, "4 read input registers"], [5, "5 write coil"],
  [6, "6 write register"], [15, "15 write coils"], [16, "16 write registers"],
  [23, "23 read/write registers"]];
// The keys the form has a field for; any other goes to "More keys" as KEY = VALUE.
const MAIN = ["name", "slave", "server", "unit", "function", "address", "quantity", "table",
  "cycle", "trigger"];

function typed(text) {
  const t = text.trim();
  if (/^[+-]?\d+$/.test(t)) return parseInt(t, 10);
  if (t === "true" || t === "false") return t === "true";
  return t.replace(/^"(.*)"$/, "$1");
}

export function scenarioForm(onSaved) {
  const input = (key, props) => adminControl(el("input", { id: `sc-${key}`, "data-key": key,
    ...props }));
  const f = {
    name: input("name", { required: true }),
    kind: adminControl(el("select", { id: "sc-kind" },
      el("option", { value: "serial", text: "a slave on the line" }),
      el("option", { value: "tcp", text: "a Modbus TCP server" }))),
    slave: input("slave", { type: "number", min: 1, max: 247 }),
    server: input("server", { placeholder: "192.168.10.45[:502]" }),
    unit: input("unit", { type: "number", min: 0, max: 255 }),
    function: adminControl(el("select", { id: "sc-function" },
      ...FUNCTIONS.map(([code, text]) => el("option", { value: code, text })))),
    address: input("address", { placeholder: "1000 (a bit: 100.3)" }),
    quantity: input("quantity", { type: "number", min: 1 }),
    table: input("table", { placeholder: "0 (a bit: 100.0)" }),
    trigger: adminControl(el("select", { id: "sc-trigger" },
      el("option", { value: "cycle", text: "every cycle" }),
      el("option", { value: "change", text: "on a change of the table" }))),
    cycle: input("cycle", { type: "number", min: 1, value: "1000" }),
    more: adminControl(el("textarea", { id: "sc-more", rows: 3,
      placeholder: "retries = 2\nstale-after = 5000\nenabled = false" })),
  };
  let editing = null;                // the name of the scenario the form changes, or null
  const out = el("pre", { id: "scenario-form-result", class: "result" });
  const title = el("h2", { id: "scenario-form-title", text: "New scenario" });
  const serialOnly = el("label", {}, "Slave address ", f.slave);
  const tcpOnly = el("span", { class: "controls" }, el("label", {}, "Server ", f.server),
    el("label", {}, "Unit ", f.unit));
  const cycleOnly = el("label", {}, "Cycle ", f.cycle, " ms");
  const sync = () => {
    serialOnly.hidden = f.kind.value !== "serial";
    tcpOnly.hidden = f.kind.value !== "tcp";
    cycleOnly.hidden = f.trigger.value !== "cycle";
  };
  f.kind.addEventListener("change", sync);
  f.trigger.addEventListener("change", sync);

  function fields() {
    const out = { name: f.name.value.trim() };
    if (f.kind.value === "serial") out.slave = typed(f.slave.value);
    else { out.server = f.server.value.trim(); out.unit = typed(f.unit.value || "1"); }
    out.function = Number(f.function.value);
    const prefix = out.function === 23 ? "read-" : "";
    for (const key of ["address", "quantity", "table"]) {
      if (f[key].value.trim()) out[prefix + key] = typed(f[key].value);
    }
    if (f.trigger.value === "change") out.trigger = "change";
    else out.cycle = typed(f.cycle.value);
    for (const line of f.more.value.split("\n")) {
      const at = line.indexOf("=");
      if (line.trim() && at > 0) out[line.slice(0, at).trim()] = typed(line.slice(at + 1));
    }
    return out;
  }

  function fill(table, asNew) {
    editing = asNew ? null : table.name;
    title.textContent = asNew ? "New scenario" : `Change scenario ${table.name}`;
    f.name.value = asNew && table.name ? `${table.name}-copy` : (table.name || "");
    f.kind.value = table.server !== undefined ? "tcp" : "serial";
    f.slave.value = table.slave ?? "";
    f.server.value = table.server ?? "";
    f.unit.value = table.unit ?? "";
    f.function.value = String(table.function ?? 3);
    const prefix = table.function === 23 ? "read-" : "";
    for (const key of ["address", "quantity", "table"]) f[key].value = table[prefix + key] ?? "";
    f.trigger.value = table.trigger === "change" ? "change" : "cycle";
    f.cycle.value = table.cycle ?? 1000;
    const used = new Set([...MAIN, ...["address", "quantity", "table"].map((k) => prefix + k)]);
    f.more.value = Object.entries(table).filter(([k]) => !used.has(k))
      .map(([k, v]) => `${k} = ${JSON.stringify(v)}`).join("\n");
    out.textContent = "";
    sync();
  }

  async function save() {
    const wanted = fields();
    const result = await act(out, "POST", "/api/scenarios/config",
      { remove: editing ? [editing] : [], add: [wanted] },
      (data) => `saved and applied: ${show(data.changed)}`);
    if (result.ok) { editing = wanted.name; onSaved(); }
  }

  async function test() {
    await testOnce(out, fields());
  }

  const element = el("section", { id: "scenario-form" }, title,
    el("form", { class: "stack", onsubmit: (e) => { e.preventDefault(); save(); } },
      el("label", {}, "Name ", f.name), el("label", {}, "Asks ", f.kind), serialOnly, tcpOnly,
      el("label", {}, "Function ", f.function), el("label", {}, "Address ", f.address),
      el("label", {}, "Quantity ", f.quantity), el("label", {}, "Table address ", f.table),
      el("label", {}, "Trigger ", f.trigger), cycleOnly,
      el("label", {}, "More keys (KEY = VALUE, see mbgw.toml(5), SCENARIOS) ", f.more),
      el("div", { class: "controls" },
        adminControl(el("button", { type: "submit", id: "scenario-save-form", text: "Save" })),
        adminControl(el("button", { type: "button", id: "scenario-try", text: "Test",
          onclick: test })),
        el("button", { type: "button", id: "scenario-new", text: "New",
          onclick: () => fill({}, true) })),
      out));
  f.function.value = "3";
  sync();
  return { element, fill };
}

// Delete the scenarios ticked in the list, after a confirmation.
export function deleteScenarios(names, out, onDone) {
  if (!names.length) {
    out.className = "result error";
    out.textContent = "tick the scenarios to delete first";
    return;
  }
  if (!confirmed(`Delete ${names.join(", ")} from the configuration?`)) return;
  act(out, "POST", "/api/scenarios/config", { remove: names, add: [] },
    (data) => `deleted: ${show(data.changed)}`).then(onDone);
}

// A one-off poll (`mbgw scenario test`): the values it read, or why none, in words.
export async function testOnce(out, fields) {
  const result = await act(out, "POST", "/api/scenarios/test", fields, (data) => (data.ok
    ? `answered in ${show(data.latency_ms)} ms: ${show(data.data)}`
    : `no good answer: ${show(data.message || data.error)}`));
  if (result.ok && !result.data.ok) out.className = "result error";
}
