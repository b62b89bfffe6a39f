// ---- One line's page (#lines/NAME): its settings in words, state, load, devices, cache -----
import { el, factsTable, table } from "./dom.js";
import { ago, isoTime, listOf, ms, show, when } from "./format.js";
import { percentile } from "./devices.js";

const PARITY = { n: "no parity", e: "even parity", o: "odd parity", m: "mark parity",
  s: "space parity" };

// "8n1" -> "8 data bits, no parity, 1 stop bit"
function formatWords(format) {
  const found = /^([78])([neoms])([12])$/.exec(String(format));
  if (!found) return show(format);
  return `${found[1]} data bits, ${PARITY[found[2]]}, ${found[3]} stop bit` +
    (found[3] === "2" ? "s" : "");
}

// "ttl=500,serve-stale=5000" -> "answers kept 500 ms, served stale up to 5000 ms ..."
function cacheWords(rule) {
  const found = /^ttl=(\d+),serve-stale=(\d+)$/.exec(String(rule));
  if (!found) return show(rule);
  return `answers kept ${found[1]} ms` + (found[2] === "0" ? ""
    : `, served up to ${found[2]} ms old after a failure`);
}

const msOr = (value, zero) => (value === 0 && zero ? zero : `${value} ms`);

// [key, label, words(value)]: the settings a line's status gives, in the order read.
const SETTINGS = [
  ["device", "Device", show],
  ["connect", "Connects to", show],
  ["protocol", "Framing", (v) => String(v).toUpperCase()],
  ["baudrate", "Speed", (v) => `${v} bit/s`],
  ["format", "Character format", formatWords],
  ["interface", "Interface", show],
  ["silence_ms", "End-of-frame silence", (v) => msOr(v, "the standard 3.5 characters")],
  ["interframe_silence_ms", "Quiet before each request", (v) => msOr(v, "none beyond t3.5")],
  ["connect_delay_ms", "Wait after connecting", (v) => msOr(v, "none")],
  ["pause_ms", "Pause before each frame", (v) => msOr(v, "none")],
  ["stout_ms", "Answer timeout (stout)", (v) => `${v} ms`],
  ["retries", "Retries after a timeout", show],
  ["down_after", "Down after", (v) => (v ? `${v} failures in a row` : "never (0)")],
  ["probe_interval_ms", "Probe while down, every", (v) => `${v} ms (doubling to 60 s)`],
  ["cache", "Read cache", cacheWords],
];

const STATE_WORDS = { up: "open", down: "down", waiting: "down, waiting for the device" };

// The line's load between two refreshes: requests/s and the share of the time it was busy.
export function lineLoad(line, before, now) {
  if (!before || now <= before.time) return ["—", "—"];
  const seconds = now - before.time;
  const requests = line.requests - before.requests;
  const busy = typeof line.busy_ms === "number" && typeof before.busy_ms === "number"
    ? line.busy_ms - before.busy_ms : null;
  return [requests >= 0 ? `${(requests / seconds).toFixed(1)}/s` : "—",
    busy !== null && busy >= 0 ? `${Math.min(100, busy / seconds / 10).toFixed(1)} %` : "—"];
}

// A remote line's connections after its first: "2: the connection to the device was opened
// again twice"
function reconnectWords(n) {
  if (!n) return "0: the first connection is the one in use";
  const times = n === 1 ? "once" : n === 2 ? "twice" : `${n} times`;
  return `${n}: the connection to the device was opened again ${times}`;
}

function stateRows(line, load) {
  const c = line.counters || {};
  const rows = [["state", STATE_WORDS[line.state] || show(line.state), "State"],
    ["state_since", when(line.state_since), "Since"],
    ["mode", line.mode === "slave" ? "slave mode: mbgw is the master on it"
      : line.mode === "master" ? "master mode: a master on it sends the requests"
        : show(line.mode), "Mode"],
    ["requests_per_s", load[0], "Requests per second"],
    ["busy", load[1], "Share of the time busy"],
    ["requests", show(line.requests), "Requests in all"],
    ["timeouts", show(line.timeouts), "Timeouts"]];
  if ("reconnects" in c) {
    rows.push(["reconnects", reconnectWords(c.reconnects), "Reconnects"],
      ["stray_replies", `${show(c.stray_replies)} dropped: late, twice, or answering no request`,
        "Stray replies"]);
  }
  return rows;
}

// A percentile's bucket bound: "≤ 5.00 ms"
const latency = (bound) => (bound === null ? "—"
  : bound === Infinity ? "over the last bucket" : `≤ ${ms(bound)}`);

function devicesTable(devices) {
  return table("line-devices", ["Address", "Health", "Since", "Last answer", "p50", "p99",
    "Failures", "Next probe"], devices.map((d) => {
    const [p50, p99] = [0.5, 0.99].map((share) => percentile(d.latency_buckets_ms, share));
    return el("tr", { "data-address": d.address },
      el("td", { class: "num", text: d.address }),
      el("td", { class: `health-${d.health}`, text: show(d.health) }),
      el("td", { text: ago(d.health_since), title: isoTime(d.health_since) }),
      el("td", { text: typeof d.last_success === "number" ? ago(d.last_success) : "never",
        title: isoTime(d.last_success) }),
      el("td", { class: "num", text: latency(p50) }),
      el("td", { class: "num", text: latency(p99) }),
      el("td", { class: "num", text: show(d.consecutive_failures) }),
      el("td", { class: "next-probe", text: typeof d.next_probe_in_s === "number"
        ? `in ${d.next_probe_in_s.toFixed(1)} s` : "—" }));
  }));
}

function cacheTable(cache) {
  const units = Object.entries((cache || {}).units || {});
  if (!units.length) return el("p", { class: "hint", text: "The cache has not served yet." });
  return table("line-cache", ["Unit", "Hits", "Coalesced", "Misses", "Served stale"],
    units.map(([unit, f]) => el("tr", { "data-unit": unit },
      ...[unit, f.hits, f.coalesced, f.misses, f.stale_served].map((v) =>
        el("td", { class: "num", text: show(v) })))));
}

// The routes that reach the line or come in on it.
export const routesOf = (routes, name) => routes.filter((r) => r.face === name ||
  r.target === `line ${name}`);

// One line's page: settings, state and load, devices, cache, its routes (routeTable(rows)).
export function linePage(line, load, routes, routeTable) {
  const settings = Object.entries(line.settings || {});
  const known = SETTINGS.filter(([k]) => k in (line.settings || {}));
  const rows = known.map(([k, label, words]) => [k, words(line.settings[k]), label]);
  for (const [k, v] of settings) {
    if (!SETTINGS.some(([s]) => s === k)) rows.push([k, show(v), k]);
  }
  const devices = listOf(line, "devices");
  return el("section", { id: "line-page", "data-line": line.name },
    el("h2", { text: `Line ${line.name}` }),
    el("div", { class: "line-columns" },
      el("div", {}, el("h3", { text: "State and load" }), factsTable("line-state",
        stateRows(line, load))),
      el("div", {}, el("h3", { text: "Settings" }), rows.length
        ? factsTable("line-settings", rows)
        : el("p", { class: "hint", text: "This line reports no settings." }))),
    el("h3", { text: `Devices (${devices.length})` }),
    devices.length ? devicesTable(devices)
      : el("p", { id: "no-line-devices", text: "No device on this line has been asked yet." }),
    ...(line.mode === "slave" ? [el("h3", { text: "Read cache" }), cacheTable(line.cache)]
      : []),
    el("h3", { text: "Routes from or to this line" }), routeTable(routesOf(routes, line.name)));
}
