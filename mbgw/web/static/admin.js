// ---- Administration: the machine, passwords, reload, restart, factory reset --------------
import { act, confirmed } from "./actions.js";
import { load } from "./api.js";
import { adminControl, clear, el, factsTable } from "./dom.js";
import { duration, isoTime, show, when } from "./format.js";
import { MIN_PASSWORD } from "./rules.js";

function systemRows(s) {
  const file = s.file || {};
  const ports = Array.isArray(s.serial_ports) ? s.serial_ports : [];
  return [
    ["host", s.host, "Host name"], ["version", s.version, "Version"], ["mode", s.mode, "Mode"],
    ["uptime", `${duration(s.uptime_s)} (since ${isoTime(s.started)})`, "Uptime"],
    ["file", show(file.path), "Configuration file"],
    ["sha256", show(file.sha256), "Its SHA-256"],
    ["modified", when(file.modified), "Last written"],
    ["ports", ports.length ? ports.map((p) => p.by_id.length
      ? `${p.device} (${p.by_id.join(", ")})` : p.device).join("; ") : "none found",
    "Serial ports"],
  ];
}

function passwordForm() {
  const role = adminControl(el("select", { id: "password-role" },
    el("option", { value: "admin", text: "admin" }),
    el("option", { value: "user", text: "user" })));
  const input = (id, label, autocomplete) => {
    const node = adminControl(el("input", { id, type: "password", autocomplete }));
    return [node, el("label", {}, label, node)];
  };
  const [current, currentLabel] = input("password-current", "Your current password ",
    "current-password");
  const [fresh, freshLabel] = input("password-new", "New password ", "new-password");
  const [again, againLabel] = input("password-again", "The new one again ", "new-password");
  const out = el("p", { id: "password-result", class: "result" });
  const submit = adminControl(el("button", { type: "submit", id: "password-change",
    text: "Change the password" }));
  const form = el("form", { id: "password-form", class: "stack", onsubmit: (e) => {
    e.preventDefault();
    if (fresh.value !== again.value) {
      out.className = "result error";
      out.textContent = "the two new passwords differ";
    } else if (fresh.value.length < MIN_PASSWORD) {
      out.className = "result error";
      out.textContent = `at least ${MIN_PASSWORD} characters`;
    } else {
      act(out, "POST", "/api/password", { role: role.value, current: current.value,
        new: fresh.value, again: again.value },
      "changed: every session has ended, log in again with the new password");
    }
  } }, el("label", {}, "Role ", role), currentLabel, freshLabel, againLabel, submit, out);
  return form;
}

// A button that asks first (when question), then calls the API and shows the outcome.
function action(id, text, path, body, done, question) {
  const out = el("span", { id: `${id}-result`, class: "result" });
  const button = adminControl(el("button", { type: "button", id, text, onclick: () => {
    if (question && !confirmed(question)) return;
    act(out, "POST", path, body, done);
  } }));
  return el("div", { class: "controls" }, button, out);
}

const reloadMessage = (data) => (data.reload && data.reload.message) || "reloaded";

export function adminPage(body) {
  const facts = el("div", { id: "system-facts" });
  body.append(
    el("h2", { text: "System" }), facts,
    el("h2", { text: "Change a password" }), passwordForm(),
    el("h2", { text: "Service" }),
    action("admin-reload", "Reload the configuration", "/api/reload", undefined,
      reloadMessage),
    action("admin-restart", "Restart the gateway", "/api/restart", undefined,
      (data) => `restarting (${data.how}): the console is back in a few seconds`,
      "Restart the gateway? Every Modbus connection is closed and the line stops for a " +
      "few seconds."),
    el("h2", { text: "Factory reset" }),
    el("p", { text: "Replaces the configuration file by the one the package ships (every " +
      "key at its built-in default). The console's address and passwords go too: the " +
      "console stops until they are set again (mbgw config password admin, mbgw config " +
      "set web listen ...)." }),
    action("admin-factory-reset", "Reset to the factory defaults", "/api/factory-reset",
      { confirm: true }, (data) => `the shipped file is back; ${reloadMessage(data)}`,
      "Reset the configuration to the factory defaults? Every setting, scenario, rule and " +
      "password of this gateway is lost, and the console stops."));
  return {
    async refresh() {
      const s = await load("/api/system");
      if (s) clear(facts).append(factsTable("system-table", systemRows(s)));
    },
  };
}
