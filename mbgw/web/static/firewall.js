// ---- Firewall: [firewall] default and the [[rule]]s: list, add, change, reorder, delete ---
import { act, confirmed } from "./actions.js";
import { load } from "./api.js";
import { adminControl, clear, el, scrollBox } from "./dom.js";
import { show } from "./format.js";

// [key, label, kind]: the keys of a [[rule]] (mbgw.toml(5), FIREWALL).
const KEYS = [["role", "Role", "text"], ["client", "Clients", "list"],
  ["listener", "Listener", "listener"], ["units", "Units", "numbers"],
  ["functions", "Functions", "numbers"], ["registers", "Registers", "numbers"],
  ["read-only", "Read only", "flag"]];

// "10.0.0.0/8, 192.168.1.7" -> ["10.0.0.0/8", "192.168.1.7"]
function listValue(text) {
  const items = text.split(",").map((t) => t.trim()).filter(Boolean);
  return items.length ? items : undefined;
}

function cell(rule, [key, , kind]) {
  const value = rule[key];
  let input;
  if (kind === "flag") {
    input = el("input", { type: "checkbox", checked: value === true });
  } else if (kind === "listener") {
    input = el("select", {}, ...["", "plain", "tls"].map((v) =>
      el("option", { value: v, text: v || "any" })));
    input.value = value || "";
  } else {
    input = el("input", { size: kind === "text" ? 8 : 14,
      value: Array.isArray(value) ? value.join(kind === "list" ? ", " : ",") : value ?? "" });
  }
  input.dataset.key = key;
  return el("td", {}, adminControl(input));
}

function ruleOf(tr) {
  const rule = {};
  for (const input of tr.querySelectorAll("[data-key]")) {
    const kind = KEYS.find(([k]) => k === input.dataset.key)[2];
    const value = kind === "flag" ? (input.checked || undefined)
      : kind === "list" ? listValue(input.value)
        : kind === "numbers" ? input.value.replace(/\s+/g, "") || undefined
          : input.value.trim() || undefined;
    if (value !== undefined) rule[input.dataset.key] = value;
  }
  return rule;
}

export function firewallPage(body) {
  const policy = adminControl(el("select", { id: "firewall-default" },
    el("option", { value: "allow", text: "allow" }),
    el("option", { value: "deny", text: "deny" })));
  const tbody = el("tbody");
  const out = el("p", { id: "firewall-result", class: "result" });
  const row = (rule, refused) => {
    const tr = el("tr", { class: "rule" }, el("td", { class: "num index" }),
      ...KEYS.map((k) => cell(rule, k)),
      el("td", { class: "num refused", text: show(refused) }),
      el("td", { class: "actions" },
        adminControl(el("button", { type: "button", class: "up", text: "↑", title: "up",
          onclick: () => { if (tr.previousSibling) tr.after(tr.previousSibling); number(); } })),
        adminControl(el("button", { type: "button", class: "down", text: "↓", title: "down",
          onclick: () => { if (tr.nextSibling) tr.before(tr.nextSibling); number(); } })),
        adminControl(el("button", { type: "button", class: "delete", text: "Delete",
          onclick: () => { tr.remove(); number(); } }))));
    return tr;
  };
  const number = () => [...tbody.children].forEach((tr, i) => {
    tr.firstChild.textContent = String(i + 1);
  });
  body.append(
    el("p", { text: "The first rule that selects a client (by role, address, listener) " +
      "says what it may do; a client no rule selects gets the default. Change, add, move " +
      "or delete rules, then apply them together: one check, one reload." }),
    el("div", { class: "controls" }, el("label", {}, "Default ", policy)),
    scrollBox(el("table", { id: "firewall-rules" }, el("thead", {}, el("tr", {},
      el("th", { text: "Rule" }), ...KEYS.map(([, label]) => el("th", { text: label })),
      el("th", { text: "Refused" }), el("th", { text: "" }))), tbody)),
    el("div", { class: "controls" },
      adminControl(el("button", { type: "button", id: "firewall-add", text: "Add a rule",
        onclick: () => { tbody.append(row({}, 0)); number(); } })),
      adminControl(el("button", { type: "button", id: "firewall-apply", text: "Apply the rules",
        onclick: () => {
          const rules = [...tbody.children].map(ruleOf);
          if (policy.value === "deny" && !confirmed("Deny every client no rule selects?")) return;
          act(out, "POST", "/api/firewall", { default: policy.value, rules },
            (data) => (data.reload && data.reload.message) || "applied").then(reload);
        } }))),
    out);

  async function reload() {
    const data = await load("/api/firewall");
    if (!data) return;
    policy.value = data.default;
    const counts = ((data.report || {}).rules || []);
    clear(tbody).append(...listOf(data.rules).map((rule, i) =>
      row(rule, (counts[i] || {}).refused)));
    number();
  }
  reload();
  return { refresh: null };
}

const listOf = (v) => (Array.isArray(v) ? v : []);
