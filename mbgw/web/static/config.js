// ---- Configuration: each key with its help, unit and choices; several changes, one reload ---
import { act } from "./actions.js";
import { load, session } from "./api.js";
import { adminControl, clear, el } from "./dom.js";
import { show } from "./format.js";

// A key's value as its field shows it: words, "on"/"off" for a flag.
function configValue(value) {
  if (value !== null && typeof value === "object" && !Array.isArray(value) && "value" in value) {
    return configValue(value.value);
  }
  if (typeof value === "boolean") return value ? "on" : "off";
  return Array.isArray(value) ? value.join(" ") : value === null ? "" : String(value);
}

// Does a key (or every key of a group) apply to the file's mode?
const applies = (about, mode) => !Array.isArray(about.modes) || about.modes.includes(mode);

export function configPage(body) {
  const holder = el("div", { id: "config-groups" });
  const fileInput = adminControl(el("input", { type: "file", id: "config-upload-file",
    accept: ".toml,text/plain" }));
  const uploadResult = el("pre", { id: "config-upload-result", class: "result" });
  const applyResult = el("p", { id: "config-apply-result", class: "result" });
  const rows = [];                   // {group, key, input, note, initial}
  const applyButton = adminControl(el("button", { type: "button", id: "config-apply",
    text: "Apply the changes", onclick: () => applyChanges(rows.filter(
      (r) => r.input.value !== r.initial), applyResult, reload) }));
  body.append(
    el("div", { class: "controls" },
      session.role === "admin" ? el("a", { href: "/api/config/file", id: "config-download",
        text: "Download the configuration file" }) : null,
      fileInput,
      adminControl(el("button", { type: "button", id: "config-upload", text: "Upload and apply",
        onclick: () => uploadConfig(fileInput, uploadResult, reload) }))),
    uploadResult,
    el("p", { class: "hint", text: "Change any number of keys, then apply them together: " +
      "they are checked as mbgw check-config does, written once and applied by one reload." }),
    el("div", { class: "controls sticky-apply" }, applyButton, applyResult),
    holder);

  async function reload() {
    const data = await load("/api/config");
    if (!data) return;
    clear(holder);
    rows.length = 0;
    if (data.file) {
      holder.append(el("p", { id: "config-file", text: `${data.file} (${data.mode} mode)` }));
    }
    const groups = Object.entries((data && data.groups) || {}).filter(([, keys]) =>
      keys && typeof keys === "object" && !Array.isArray(keys));
    for (const [group, keys] of groups) {
      const shown = Object.entries(keys).filter(([, about]) => applies(about, data.mode));
      if (!shown.length) continue;           // e.g. [transparent] in slave mode
      holder.append(el("fieldset", { "data-group": group }, el("legend", { text: `[${group}]` }),
        ...shown.map(([key, about]) => configRow(group, key, about, rows))));
    }
  }
  reload();
  return { refresh: null };
}

function field(group, key, about) {
  const value = configValue(about);
  const id = `cfg-${group}-${key}`;
  const choices = Array.isArray(about.choices) ? about.choices : [];
  if (!choices.length) {
    return el("input", { id, "data-field": `${group}.${key}`, value });
  }
  const options = choices.includes(value) ? choices : [value, ...choices];
  const select = el("select", { id, "data-field": `${group}.${key}` },
    ...options.map((c) => el("option", { value: c, text: c })));
  select.value = value;
  return select;
}

function configRow(group, key, about, rows) {
  const name = `${group}.${key}`;
  const input = adminControl(field(group, key, about));
  const note = el("span", { class: "result", "data-error-for": name });
  const row = { group, key, input, note, initial: input.value };
  rows.push(row);
  input.addEventListener("input", () => {
    input.classList.toggle("changed", input.value !== row.initial);
  });
  // the answer comes once the daemon has reloaded the file: applied, or what it did not do
  const set = async () => {
    const result = await act(note, "POST", "/api/config",
      { group, key, value: input.value }, "applied");
    if (result.ok) { row.initial = input.value; input.classList.remove("changed"); }
    if (!result.ok && result.data.field && result.data.field !== name) {
      note.textContent += ` (${result.data.field})`;
    }
  };
  return el("div", { class: "config-row", "data-key": name },
    el("label", { for: input.id, text: key }), input,
    about.unit ? el("span", { class: "unit", text: about.unit }) : null,
    adminControl(el("button", { type: "button", class: "config-save", text: "Set",
      onclick: set })),
    note,
    about.help ? el("div", { class: "help", text: about.help }) : null);
}

async function applyChanges(changed, out, reload) {
  for (const r of changed) { r.note.className = "result"; r.note.textContent = ""; }
  if (!changed.length) {
    out.className = "result error";
    out.textContent = "nothing changed";
    return;
  }
  const names = changed.map((r) => `${r.group}.${r.key}`);
  const result = await act(out, "POST", "/api/config", {
    changes: changed.map((r) => ({ group: r.group, key: r.key, value: r.input.value })) },
  `applied by one reload: ${names.join(", ")}`);
  const refused = changed.find((r) => `${r.group}.${r.key}` === result.data.field);
  if (!result.ok && refused) {
    refused.note.className = "result error";
    refused.note.textContent = result.data.error;
  }
  if (result.ok || result.data.written) reload();
}

async function uploadConfig(input, out, reload) {
  const file = input.files && input.files[0];
  if (!file) { out.className = "result error"; out.textContent = "choose a file first"; return; }
  const result = await act(out, "POST", "/api/config/file", await file.text(),
    "written and applied");
  const problems = result.data.problems;
  if (!result.ok && Array.isArray(problems) && problems.length) {
    out.textContent = problems.map(show).join("\n");
  }
  if (result.data.written) reload();
}
