// ---- Scenarios: VPGate's colours, errors in words and since when, enable/disable, test -----
import { act } from "./actions.js";
import { api, load } from "./api.js";
import { adminControl, el, liveTable } from "./dom.js";
import { deleteScenarios, scenarioForm, testOnce } from "./scenario_form.js";
import { ago, isoTime, listOf, ms, show, words } from "./format.js";

// {"timeout": 45, "crc": 2}: "45 timeouts, 2 CRC"; "none".
export function errorWords(errors) {
  if (!errors || typeof errors !== "object") return show(errors);
  const parts = Object.entries(errors).filter(([, n]) => n)
    .map(([kind, n]) => `${n} ${words(kind).toLowerCase()}`);
  return parts.length ? parts.join(", ") : "none";
}

// In error since when: "2026-11-27 17:40:40 (00:03:12 ago)".
function errorSince(s) {
  return s.state === "error" && typeof s.error_since === "number"
    ? `${isoTime(s.error_since)} (${ago(s.error_since)})` : "";
}

export function scenariosPage(body) {
  const result = el("p", { id: "scenarios-message", class: "result" });
  const save = adminControl(el("input", { type: "checkbox", id: "scenario-save" }));
  let tables = new Map();            // the file's [[scenario]] tables by name
  const ticked = new Set();
  const form = scenarioForm(() => page.refresh());
  const place = (s) => {
    const t = tables.get(s.name) || {};
    const p = t.function === 23 ? "read-" : "";
    return t[`${p}address`] === undefined ? "—"
      : `${t[`${p}address`]} ×${show(t[`${p}quantity`])} → table ${show(t[`${p}table`])}`;
  };
  const table = liveTable("scenarios-table", [
    { label: "", render: (td, s, isNew) => {
      if (!isNew) return;
      td.append(adminControl(el("input", { type: "checkbox", class: "tick",
        "aria-label": `select ${s.name}`, onchange: (e) => {
          if (e.target.checked) ticked.add(s.name); else ticked.delete(s.name);
        } })));
    } },
    { label: "Name", get: (s) => s.name, cls: () => "name" },
    { label: "Kind", get: (s) => s.kind },
    { label: "Target", get: (s) => s.target },
    { label: "Function", get: (s) => s.function, num: true },
    { label: "Address, quantity, table", get: place, cls: () => "place" },
    { label: "Trigger", get: (s) => s.trigger },
    { label: "State", render: (td, s) => {
      td.replaceChildren(el("span", { class: `state state-${s.state}`, text: s.state }));
    } },
    { label: "Message", get: (s) => s.message || "", cls: () => "message" },
    { label: "In error since", get: errorSince, cls: () => "error-since" },
    { label: "Runs", get: (s) => s.runs, num: true },
    { label: "Successes", get: (s) => s.successes, num: true },
    { label: "Errors", get: (s) => errorWords(s.errors), cls: () => "errors" },
    { label: "Last success", get: (s) => isoTime(s.last_success) },
    { label: "Latency", get: (s) => ms(s.last_latency_ms), num: true },
    { label: "Data age", get: (s) => typeof s.data_age_s === "number"
      ? `${s.data_age_s.toFixed(1)} s${s.stale ? " (stale)" : ""}` : "—" },
    { label: "", cls: () => "actions", render: (td, s, isNew) => {
      if (isNew) {
        td.append(
          adminControl(el("button", { type: "button", class: "enable", text: "Enable",
            onclick: () => enable(s.name, true, save.checked, result) })), " ",
          adminControl(el("button", { type: "button", class: "disable", text: "Disable",
            onclick: () => enable(s.name, false, save.checked, result) })), " ",
          el("button", { type: "button", class: "edit", text: "Edit", onclick: () => {
            form.fill(tables.get(s.name) || { name: s.name }, false);
            form.element.scrollIntoView();
          } }), " ",
          el("button", { type: "button", class: "duplicate", text: "Duplicate", onclick: () => {
            form.fill(tables.get(s.name) || { name: s.name }, true);
            form.element.scrollIntoView();
          } }));
      }
    } },
  ], (s) => `${s.kind}/${s.name}`);
  const fields = el("textarea", { id: "scenario-test-fields", rows: 6,
    placeholder: "slave = 1\nfunction = 3\naddress = 0\nquantity = 2\ntable = 100" });
  const out = el("pre", { id: "scenario-test-result" });
  const testButton = adminControl(el("button", { type: "button", id: "scenario-test",
    text: "Run the test", onclick: () => testScenario(fields.value, out) }));
  const remove = adminControl(el("button", { type: "button", id: "scenarios-delete",
    text: "Delete the ticked scenarios", onclick: () => deleteScenarios([...ticked], result,
      () => { ticked.clear(); page.refresh(); }) }));
  body.append(result,
    el("p", {}, el("label", {}, save, " enable / disable also in the configuration file")),
    table.element, el("div", { class: "controls" }, remove), form.element,
    el("h2", { text: "Test any request" }),
    el("p", { text: "One KEY = VALUE per line, as in a [[scenario]] table of the file." }),
    fields, el("div", { class: "controls" }, testButton), out);
  const page = {
    async refresh() {
      const data = await load("/api/scenarios");
      if (!data) return;
      const rows = listOf(data, "scenarios");
      table.update(rows);                   // the states first, then the file's places
      const file = await api("GET", "/api/scenarios/config");   // 404: no file
      tables = new Map(listOf(file.ok ? file.data : null, "scenarios").map((t) => [t.name, t]));
      table.update(rows);
    },
  };
  return page;
}

function enable(name, on, save, out) {
  act(out, "POST", `/api/scenarios/${encodeURIComponent(name)}/${on ? "enable" : "disable"}`,
    { save }, `scenario ${name} ${on ? "enabled" : "disabled"}`);
}

// "KEY = VALUE" lines: an object; a VALUE that reads as JSON (a number, true, [1, 2], "text")
// is that, else the text.
function fieldsOf(text) {
  const fields = {};
  for (const line of text.split("\n")) {
    const t = line.trim();
    if (!t || t.startsWith("#")) continue;
    const at = t.indexOf("=");
    if (at < 1) throw new Error(`${t}: expected KEY = VALUE`);
    const value = t.slice(at + 1).trim();
    try { fields[t.slice(0, at).trim()] = JSON.parse(value); } catch (e) {
      fields[t.slice(0, at).trim()] = value;
    }
  }
  return fields;
}

async function testScenario(text, out) {
  let fields;
  try { fields = fieldsOf(text); } catch (err) { out.textContent = err.message; return; }
  await testOnce(out, fields);
}
