// ---- Configuration: the file's keys, set with the checks of `mbgw config set` ---------------
import { api, load, refusal, session } from "./api.js";
import { adminControl, clear, el } from "./dom.js";
import { show } from "./format.js";

// {group: {key: value}} from GET /api/config (a value may be {"value": ...}).
function configGroups(data) {
  const groups = data && typeof data.groups === "object" ? data.groups : data;
  return Object.entries(groups || {}).filter(([, keys]) =>
    keys && typeof keys === "object" && !Array.isArray(keys));
}

function configValue(value) {
  if (value !== null && typeof value === "object" && !Array.isArray(value) && "value" in value) {
    return configValue(value.value);
  }
  return Array.isArray(value) ? value.join(" ") : value === null ? "" : String(value);
}

export function configPage(body) {
  const holder = el("div", { id: "config-groups" });
  const fileInput = adminControl(el("input", { type: "file", id: "config-upload-file",
    accept: ".toml,text/plain" }));
  const uploadResult = el("pre", { id: "config-upload-result" });
  body.append(
    el("div", { class: "controls" },
      session.role === "admin" ? el("a", { href: "/api/config/file", id: "config-download",
        text: "Download the configuration file" }) : null,
      fileInput,
      adminControl(el("button", { type: "button", id: "config-upload", text: "Upload and apply",
        onclick: () => uploadConfig(fileInput, uploadResult, reload) }))),
    uploadResult, holder);

  async function reload() {
    const data = await load("/api/config");
    if (!data) return;
    clear(holder);
    if (data.file) {
      holder.append(el("p", { id: "config-file", text: `${data.file} (${data.mode} mode)` }));
    }
    for (const [group, keys] of configGroups(data)) {
      holder.append(el("fieldset", { "data-group": group }, el("legend", { text: `[${group}]` }),
        ...Object.entries(keys).map(([key, value]) => configRow(group, key, value))));
    }
  }
  reload();
  return { refresh: null };
}

function configRow(group, key, value) {
  const field = `${group}.${key}`;
  const input = adminControl(el("input", { id: `cfg-${group}-${key}`, "data-field": field,
    value: configValue(value) }));
  const note = el("span", { class: "field-error", "data-error-for": field });
  // the answer comes once the daemon has reloaded the file: applied, or what it did not do
  const apply = async () => {
    note.className = "";
    note.textContent = "applying...";
    const result = await api("POST", "/api/config", { group, key, value: input.value });
    note.className = result.ok ? "ok" : "field-error";
    note.textContent = result.ok ? "applied" : refusal(result);
    if (!result.ok && result.data.field && result.data.field !== field) {
      note.textContent += ` (${result.data.field})`;
    }
  };
  return el("div", { class: "config-row" },
    el("label", { for: input.id, text: key }), input,
    adminControl(el("button", { type: "button", class: "config-save", text: "Set",
      onclick: apply })),
    note);
}

async function uploadConfig(input, out, reload) {
  const file = input.files && input.files[0];
  if (!file) { out.className = "error"; out.textContent = "choose a file first"; return; }
  out.className = "";
  out.textContent = "checking, writing and applying...";
  const result = await api("POST", "/api/config/file", await file.text());
  out.className = result.ok ? "ok" : "error";
  if (result.ok) {
    out.textContent = "written and applied";
  } else {
    const problems = result.data.problems;
    out.textContent = Array.isArray(problems) && problems.length
      ? problems.map(show).join("\n") : refusal(result);
  }
  if (result.data.written) reload();
}

