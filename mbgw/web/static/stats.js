// ---- Statistics: the counters grouped as an operator reads them, with rates per second ----
import { act, confirmed } from "./actions.js";
import { load } from "./api.js";
import { block } from "./blocks.js";
import { adminControl, clear, el, scrollBox, table } from "./dom.js";
import { figure, listOf, ms, show, when, words } from "./format.js";
import { percentile } from "./devices.js";
import { errorWords } from "./scenarios.js";

// Which group a line counter belongs to, by its name.
function counterGroup(name) {
  if (name.includes("tls")) return "TLS";
  if (name.startsWith("connections_")) return "Clients";
  return "Line";
}

// Rows [path, value, label, per second] with the rate since the last refresh.
function counterRows(counters, rates, prefix, filter) {
  return Object.entries(counters || {}).filter(([k]) => filter(k)).map(([k, v]) => {
    const path = `${prefix}.${k}`;
    return [path, figure(k, v), words(k), rates(path, v)];
  });
}

function ratedTable(id, rows) {
  return scrollBox(el("table", { id, class: "facts" },
    el("thead", {}, el("tr", {}, el("th", { text: "" }), el("th", { text: "Total" }),
      el("th", { text: "Per second" }))),
    el("tbody", {}, ...rows.map(([path, value, label, rate]) =>
      el("tr", { "data-name": path }, el("th", { text: label }),
        el("td", { class: "num", text: value }), el("td", { class: "num rate", text: rate }))))));
}

function devicesTable(devices) {
  return table("stats-devices", ["Line", "Address", "Health", "Requests", "Failures",
    "p50", "p99", "Exceptions"], devices.map((d) => el("tr",
    { "data-name": `devices.${d.address}` },
    el("td", { text: show(d.line) }), el("td", { class: "num", text: d.address }),
    el("td", { class: `health-${d.health}`, text: show(d.health) }),
    el("td", { class: "num", text: show(d.transactions ?? d.requests) }),
    el("td", { class: "num", text: show(d.consecutive_failures) }),
    el("td", { class: "num", text: ms(percentile(d.latency_buckets_ms, 0.5)) }),
    el("td", { class: "num", text: ms(percentile(d.latency_buckets_ms, 0.99)) }),
    el("td", { text: errorWords(d.exceptions) }))));
}

function scenariosTable(scenarios) {
  return table("stats-scenarios", ["Name", "State", "Runs", "Successes", "Errors", "Retries",
    "Overruns"], scenarios.map((s) => el("tr", { "data-name": `scenarios.${s.name}` },
    el("td", { text: show(s.name) }),
    el("td", {}, el("span", { class: `state state-${s.state}`, text: show(s.state) })),
    ...[s.runs, s.successes].map((n) => el("td", { class: "num", text: show(n) })),
    el("td", { text: errorWords(s.errors) }),
    ...[s.retries, s.overruns].map((n) => el("td", { class: "num", text: show(n) })))));
}

const KNOWN = new Set(["counters", "counters_since", "line_utilisation_pct", "line_load_pct",
  "devices", "scenarios", "table", "firewall"]);

export function statsPage(body) {
  const message = el("p", { id: "stats-message", class: "result" });
  const holder = el("div", { id: "stats-table" });
  let before = new Map();           // path -> [value, time] of the last refresh
  body.append(el("div", { class: "controls" }, adminControl(el("button", {
    type: "button", id: "stats-reset", text: "Reset the counters", onclick: () => {
      if (!confirmed("Reset every counter and device figure to zero?")) return;
      act(message, "POST", "/api/stats/reset", undefined, "counters reset");
    } })), message), holder);
  return {
    async refresh() {
      const data = await load("/api/stats");
      if (!data) return;
      const now = Date.now() / 1000;
      const after = new Map();
      const rates = (path, value) => {
        after.set(path, [value, now]);
        const last = before.get(path);
        if (!last || typeof value !== "number" || value < last[0] || now <= last[1]) return "—";
        return `${((value - last[0]) / (now - last[1])).toFixed(1)}/s`;
      };
      const counters = data.counters || {};
      const groups = ["Line", "Clients", "TLS"].map((group) => [group,
        counterRows(counters, rates, "counters", (k) => counterGroup(k) === group)]);
      const line = groups[0][1];
      line.unshift(["counters_since", when(data.counters_since), "Counted since", ""]);
      if (typeof data.line_utilisation_pct === "number") {
        line.unshift(["line_load", `${data.line_utilisation_pct} % on average`, "Line load",
          Object.entries(data.line_load_pct || {}).map(([k, v]) => `${v} % (${k})`).join(", ")]);
      }
      const sections = [];
      for (const [group, rows] of groups) {
        if (rows.length) sections.push(el("h2", { text: group }), ratedTable(null, rows));
      }
      const devices = listOf(data, "devices");
      if (devices.length) sections.push(el("h2", { text: "Devices" }), devicesTable(devices));
      const scenarios = listOf(data, "scenarios");
      if (scenarios.length) {
        sections.push(el("h2", { text: "Scenarios" }), scenariosTable(scenarios));
      }
      for (const key of ["table", "firewall"]) {
        if (data[key]) sections.push(el("h2", { text: words(key) }), block(key, data[key]));
      }
      for (const [key, value] of Object.entries(data)) {
        if (!KNOWN.has(key) && value !== null && typeof value === "object" &&
            Object.keys(value).length) {
          sections.push(el("h2", { text: words(key) }), block(key, value));
        }
      }
      before = after;
      clear(holder).append(...sections);
    },
  };
}
