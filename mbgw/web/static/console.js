// The mbgw web console: one page, hash routes, plain JS over the JSON API (/api/...).
// Every value from the gateway is inserted as text (textContent / createTextNode), never as
// markup: a client's address, a scenario's name or a trace payload cannot inject anything.
"use strict";

const POLL_MS = 1000;            // live pages refresh once a second
const TRACE_ROWS = 500;          // rows the Traffic page keeps on screen
const TRACE_KEPT = 20000;        // events kept for the pcap download (the oldest go first)

const session = { role: null, csrf: null };
let current = null;              // the page shown: {refresh, leave}
let timer = null;

// ---- DOM helpers -------------------------------------------------------------------------

// el("td", {class: "num", text: 42}, child...): an element; "text" is set as textContent,
// on* entries are listeners, booleans are properties (disabled, checked), the rest attributes.
function el(tag, props, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(props || {})) {
    if (value === undefined || value === null) continue;
    if (name === "text") node.textContent = String(value);
    else if (name.startsWith("on")) node.addEventListener(name.slice(2), value);
    else if (typeof value === "boolean" || name === "value") node[name] = value;
    else node.setAttribute(name, String(value));
  }
  for (const child of children) {
    if (child === null || child === undefined) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

function $(id) { return document.getElementById(id); }

function clear(node) { while (node.firstChild) node.removeChild(node.firstChild); return node; }

// An admin's control: disabled for the user role (the API refuses it anyway).
function adminControl(node) {
  if (session.role !== "admin") {
    node.disabled = true;
    node.title = "admin only";
  }
  node.classList.add("admin-only");
  return node;
}

function show(value) {
  if (value === null || value === undefined) return "—";
  if (Array.isArray(value)) return value.map(show).join(", ");
  if (typeof value === "object") return JSON.stringify(value);
  return String(value);
}

function localTime(unix) {
  if (typeof unix !== "number") return "—";
  return new Date(unix * 1000).toLocaleString();
}

function clock(unix) {
  const d = new Date(unix * 1000);
  const pad = (n, w) => String(n).padStart(w || 2, "0");
  return `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}.` +
         pad(d.getMilliseconds(), 3);
}

function ago(unix) {
  if (typeof unix !== "number") return "—";
  return duration(Math.max(0, Date.now() / 1000 - unix)) + " ago";
}

function duration(seconds) {
  if (typeof seconds !== "number") return "—";
  const s = Math.floor(seconds);
  const days = Math.floor(s / 86400);
  const hms = [Math.floor(s / 3600) % 24, Math.floor(s / 60) % 60, s % 60]
    .map((n) => String(n).padStart(2, "0")).join(":");
  return days ? `${days} d ${hms}` : hms;
}

// "12.0 % (10 s), 8.1 % (1 min), 7.9 % on average": the line's load now and since the reset.
function lineLoad(s) {
  const load = s.line_load_pct || {};
  const now = [["10s", "10 s"], ["1min", "1 min"]].filter(([k]) => typeof load[k] === "number")
    .map(([k, label]) => `${load[k]} % (${label}), `).join("");
  return `${now}${s.line_utilisation_pct} % on average`;
}

// "12", "0x1F" or "1fh": a number, or NaN.
function parseNumber(text) {
  const t = String(text).trim().toLowerCase();
  if (/^0x[0-9a-f]+$/.test(t)) return parseInt(t.slice(2), 16);
  if (/^[0-9a-f]+h$/.test(t)) return parseInt(t.slice(0, -1), 16);
  if (/^[0-9]+$/.test(t)) return parseInt(t, 10);
  return NaN;
}

function hex4(n) { return "0x" + n.toString(16).toUpperCase().padStart(4, "0"); }

function listOf(data, key) {
  if (Array.isArray(data)) return data;
  return (data && Array.isArray(data[key])) ? data[key] : [];
}

// ---- the API -----------------------------------------------------------------------------

// {ok, status, data}; data.error says why when not ok.  A 401 (session gone) shows the login.
async function api(method, path, body) {
  const headers = { "Accept": "application/json" };
  const options = { method, headers, credentials: "same-origin" };
  if (typeof body === "string") {                // a file's text, as it is
    headers["Content-Type"] = "text/plain; charset=utf-8";
    options.body = body;
  } else if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    options.body = JSON.stringify(body);
  }
  if (method !== "GET" && session.csrf) headers["X-CSRF-Token"] = session.csrf;
  let response;
  try {
    response = await fetch(path, options);
  } catch (err) {
    return { ok: false, status: 0, data: { error: "the gateway does not answer" } };
  }
  let data = null;
  if ((response.headers.get("Content-Type") || "").includes("json")) {
    data = await response.json().catch(() => null);
  }
  if (!response.ok && !(data && data.error)) {
    data = { ...(data || {}), error: `${response.status} ${response.statusText}` };
  }
  if (response.status === 401 && path !== "/api/login" && session.role) {
    showLogin("The session has expired: log in again.");
  }
  return { ok: response.ok, status: response.status, data: data || {} };
}

function refusal(result) {
  if (result.status === 403 && session.role !== "admin") {
    return `refused: ${result.data.error} (the user role only reads)`;
  }
  return result.data.error;
}

// ---- log in / out ------------------------------------------------------------------------

function showLogin(message) {
  session.role = session.csrf = null;
  leavePage();
  $("nav").hidden = $("who").hidden = $("page").hidden = true;
  $("login-page").hidden = false;
  $("login-error").textContent = message || "";
  $("login-password").value = "";
  $("login-password").focus();
}

function loggedIn(data) {
  session.role = data.role;
  session.csrf = data.csrf;
  document.body.dataset.role = data.role;
  $("login-page").hidden = true;
  $("nav").hidden = $("who").hidden = $("page").hidden = false;
  $("role").textContent = data.role;
  route();
}

async function logIn(event) {
  event.preventDefault();
  const result = await api("POST", "/api/login",
    { user: $("login-user").value, password: $("login-password").value });
  if (result.ok) {
    loggedIn(result.data);
  } else {
    $("login-password").value = "";
    $("login-error").textContent = result.status === 429
      ? `Too many attempts: wait a minute. (${result.data.error})`
      : result.status === 401 ? "Wrong user or password." : result.data.error;
  }
}

async function logOut() {
  await api("POST", "/api/logout");
  showLogin("Logged out.");
}

// ---- pages -------------------------------------------------------------------------------

const pages = {
  overview: { title: "Overview", build: overviewPage },
  clients: { title: "Clients", build: clientsPage },
  devices: { title: "Devices", build: devicesPage },
  scenarios: { title: "Scenarios", build: scenariosPage },
  table: { title: "Exchange table", build: tablePage },
  lines: { title: "Lines", build: linesPage },
  stats: { title: "Statistics", build: statsPage },
  traffic: { title: "Traffic", build: trafficPage },
  config: { title: "Configuration", build: configPage },
};

function leavePage() {
  if (timer !== null) clearInterval(timer);
  timer = null;
  if (current && current.leave) current.leave();
  current = null;
}

function route() {
  if (!session.role) return;
  const wanted = location.hash.slice(1);
  const name = Object.hasOwn(pages, wanted) ? wanted : "overview";
  leavePage();
  for (const link of document.querySelectorAll("nav a")) {
    link.classList.toggle("current", link.getAttribute("href") === "#" + name);
  }
  $("page-title").textContent = pages[name].title;
  $("page-error").textContent = "";
  const body = clear($("page-body"));
  body.dataset.page = name;
  current = pages[name].build(body);
  if (current.refresh) {
    let busy = false;
    const tick = async () => {
      if (busy) return;
      busy = true;
      try { await current.refresh(); } finally { busy = false; }
    };
    tick();
    if (current.live !== false) timer = setInterval(tick, POLL_MS);
  }
}

// GET a page's data; on failure the page's error line says why (and the page keeps its last).
async function load(path) {
  const result = await api("GET", path);
  $("page-error").textContent = result.ok ? "" : result.data.error;
  return result.ok ? result.data : null;
}

// A table whose rows are kept by key across refreshes (a button being clicked stays the same
// element).  columns: [{label, get(item) -> value, cls(item) -> class, num, render(td, item,
// isNew)}].
function liveTable(id, columns, key) {
  const rows = new Map();
  const tbody = el("tbody");
  const table = el("table", { id }, el("thead", {}, el("tr", {},
    ...columns.map((c) => el("th", { text: c.label })))), tbody);
  const empty = el("p", { class: "empty", text: "none" });
  function update(items) {
    const seen = new Set();
    for (const item of items) {
      const k = String(key(item));
      seen.add(k);
      let tr = rows.get(k);
      const isNew = !tr;
      if (isNew) {
        tr = el("tr", { "data-key": k }, ...columns.map(() => el("td")));
        rows.set(k, tr);
      }
      columns.forEach((c, i) => {
        const td = tr.children[i];
        if (c.render) c.render(td, item, isNew);
        else td.textContent = show(c.get(item));
        td.className = [c.num ? "num" : "", c.cls ? c.cls(item) : ""].join(" ").trim();
      });
      tbody.append(tr);             // in the order given (moves an existing row)
    }
    for (const [k, tr] of rows) {
      if (!seen.has(k)) { tr.remove(); rows.delete(k); }
    }
    empty.hidden = items.length > 0;
  }
  return { element: el("div", {}, table, empty), update };
}

// Rows [name, value] as a two-column table (rebuilt: nothing in it is clicked).
function factsTable(id, rows) {
  return el("table", { id }, el("tbody", {}, ...rows.map(([name, value]) =>
    el("tr", { "data-name": name }, el("th", { text: name }),
       el("td", { class: typeof value === "number" ? "num" : "", text: show(value) })))));
}

// Every leaf of a JSON document, with its dotted path.
function leaves(value, prefix, out) {
  if (value !== null && typeof value === "object" && !Array.isArray(value)) {
    for (const [k, v] of Object.entries(value)) leaves(v, prefix ? `${prefix}.${k}` : k, out);
  } else if (Array.isArray(value) && value.some((v) => v !== null && typeof v === "object")) {
    value.forEach((v, i) => leaves(v, `${prefix}.${i}`, out));
  } else {
    out.push([prefix, value]);
  }
  return out;
}

// ---- Overview ----------------------------------------------------------------------------

const ERROR_COUNTERS = ["timeouts", "crc_errors", "invalid_frames", "gateway_exceptions",
  "echo_errors", "unreachable", "wrong_unit", "wrong_function", "frame_errors", "overruns"];
const ACTIVITY_COUNTERS = ["requests", "replies", "frames_stored", "frames_sent",
  "bytes_received"];

function sum(counters, names) {
  return names.reduce((total, n) => total + (typeof counters[n] === "number" ? counters[n] : 0), 0);
}

function led(id, label) {
  const value = el("span", { class: "value" });
  const node = el("div", { class: "led", id }, el("span", { class: "lamp" }), label, value);
  return {
    node,
    set(colour, text) {
      node.className = "led" + (colour ? " on-" + colour : "");
      node.dataset.state = colour || "off";
      value.textContent = text;
    },
  };
}

function listening(status) {
  const out = [];
  if (Array.isArray(status.listening)) out.push(...status.listening.map(show));
  if (status.upstream && status.upstream.port) {
    out.push(`Modbus TCP servers on port ${status.upstream.port}`);
  }
  const table = status.table || {};
  if (table.tcp && table.tcp.port) out.push(`table :${table.tcp.port}`);
  const t = status.transparent || {};
  if (t.raw_port) out.push(`raw :${t.raw_port}`);
  if (status.web && status.web.listen) out.push(`web ${show(status.web.listen)}`);
  return out.length ? out.join(", ") : "—";
}

function overviewPage(body) {
  const facts = el("div");
  const panelLeds = {
    line: led("led-line", "Line"),
    activity: led("led-activity", "Activity"),
    errors: led("led-errors", "Errors"),
    scenarios: led("led-scenarios", "Scenario errors"),
    devices: led("led-devices", "Devices down"),
  };
  const wrong = el("ul", { id: "overview-wrong" });
  body.append(el("div", { class: "panel", id: "front-panel" },
    ...Object.values(panelLeds).map((l) => l.node)),
    el("h2", { text: "What is wrong, since when" }), wrong,
    el("h2", { text: "Gateway" }), facts);
  let previous = null;
  return {
    async refresh() {
      const s = await load("/api/status");
      if (!s) return;
      const serial = s.serial || { state: linesState(s) };
      const counters = s.counters || {};
      // a slave-mode file may leave [serial] out: its [[line]]s are the lines
      const line = s.serial ? [["Serial device", `${show(serial.device)} ` +
          `${serial.protocol === undefined ? "" : serial.protocol + " "}` +
          `${show(serial.baudrate)} ${show(serial.format)} ${show(serial.interface)}`]]
        : [["Lines", listOf(s, "lines").map((l) => l.name).join(", ")]];
      clear(facts).append(factsTable("overview-facts", [
        ["Location", s.location], ["Mode", s.mode], ["Version", s.version],
        ...line, ["Line state", serial.state], ["Uptime", duration(s.uptime_s)],
        ["Started", localTime(s.started)],
        ["Line load", typeof s.line_utilisation_pct === "number"
          ? lineLoad(s) : "—"],
        ["Listening", listening(s)],
        ...(Array.isArray(s.clients) ? [["Clients", String(s.clients.length)]] : []),
        ["Devices", tally(s.devices || [], "health")],
        ["Scenarios", tally(s.scenarios || [], "state")],
        ["Counters since", localTime(s.counters_since)],
      ]));
      const problems = troubles(s);
      clear(wrong).append(...(problems.length ? problems.map((p) => el("li", { text: p }))
        : [el("li", { class: "ok", text: "Nothing: the line is up, every device answers, " +
          "every scenario runs." })]));
      const activity = sum(counters, ACTIVITY_COUNTERS);
      const errors = sum(counters, ERROR_COUNTERS);
      const scenarioErrors = (s.scenarios || []).filter((sc) => sc.state === "error");
      const down = (s.devices || []).filter((d) => d.health === "down");
      panelLeds.line.set(serial.state === "up" ? "green" : "red", show(serial.state));
      panelLeds.activity.set(previous && activity > previous.activity ? "green" : "",
        `${activity}`);
      panelLeds.errors.set(previous && errors > previous.errors ? "red" : errors ? "amber" : "",
        `${errors}`);
      panelLeds.scenarios.set(scenarioErrors.length ? "red" : "",
        scenarioErrors.length ? scenarioErrors.map((sc) => sc.name).join(", ") : "0");
      panelLeds.devices.set(down.length ? "red" : "",
        down.length ? down.map((d) => d.address).join(", ") : "0");
      previous = { activity, errors };
    },
  };
}

// "2 up, 1 down": how many items have each value of a field.
function tally(items, field) {
  if (!items.length) return "none";
  const counts = new Map();
  for (const item of items) counts.set(item[field], (counts.get(item[field]) || 0) + 1);
  return [...counts].map(([value, n]) => `${n} ${value}`).join(", ");
}

// Without line serial: "up" while every line is, else the first other state.
function linesState(s) {
  const other = listOf(s, "lines").find((l) => l.state !== "up");
  return other ? other.state : "up";
}

// What an operator must look at, each with since when.
function troubles(s) {
  const out = [];
  const serial = s.serial || {};
  if (serial.state && serial.state !== "up") {
    out.push(`The serial line ${show(serial.device)} is ${serial.state}.`);
  }
  for (const d of s.devices || []) {
    if (d.health !== "up") {
      out.push(`Device ${d.address} is ${d.health} since ${localTime(d.health_since)}` +
        (typeof d.last_success === "number" ? ` (last answer ${localTime(d.last_success)}).`
          : " (it never answered)."));
    }
  }
  for (const sc of s.scenarios || []) {
    if (sc.state === "error") {
      out.push(`Scenario ${sc.name} is in error: ${sc.message || "?"}` +
        (typeof sc.last_success === "number" ? ` (last success ${localTime(sc.last_success)}).`
          : " (never succeeded)."));
    } else if (sc.stale) {
      out.push(`Scenario ${sc.name}'s data is stale (${show(sc.data_age_s)} s old).`);
    }
  }
  const persist = (s.table || {}).persist || {};
  if (persist.failing) {
    out.push(`The exchange table is not kept since ${localTime(persist.failing_since)}: ` +
      `${persist.failing}.`);
  }
  return out;
}

// ---- Clients -----------------------------------------------------------------------------

function clientsPage(body) {
  const message = el("p", { id: "clients-message" });
  const table = liveTable("clients-table", [
    { label: "ID", get: (c) => c.id, num: true },
    { label: "Address", get: (c) => c.peer, cls: () => "peer" },
    { label: "Listener", get: (c) => c.listener },
    { label: "Role", get: (c) => c.role },
    { label: "Connected since", get: (c) => localTime(c.connected_since) },
    { label: "Requests", get: (c) => c.requests, num: true },
    { label: "In flight", get: (c) => c.in_flight, num: true },
    { label: "Last activity", get: (c) => ago(c.last_activity) },
    { label: "", cls: () => "actions", render: (td, c, isNew) => {
      if (!isNew) return;
      td.append(adminControl(el("button", { type: "button", class: "close-client",
        text: "Close", onclick: () => closeClient(c.id, message) })));
    } },
  ], (c) => c.id);
  body.append(message, table.element);
  return {
    async refresh() {
      const data = await load("/api/clients");
      if (data) table.update(listOf(data, "clients"));
    },
  };
}

async function closeClient(id, message) {
  const result = await api("POST", `/api/clients/${encodeURIComponent(id)}/close`);
  message.className = result.ok ? "ok" : "error";
  message.textContent = result.ok ? `client ${id} closed` : refusal(result);
}

// ---- Devices -----------------------------------------------------------------------------

const DEVICE_FIXED = ["line", "address", "health", "health_since", "last_success",
  "consecutive_failures", "latency_sum_ms", "upstream", "diagnosis", "learnt_p99_ms",
  "probe_timeout_ms", "stout_ms"];

function ms(value) {
  return typeof value === "number" ? value.toFixed(1) : "—";
}

function devicesPage(body) {
  const holder = el("div");
  body.append(holder);
  return {
    async refresh() {
      const data = await load("/api/devices");
      if (!data) return;
      const devices = listOf(data, "devices");
      const counts = devices.length
        ? Object.keys(devices[0]).filter((k) => !DEVICE_FIXED.includes(k) &&
            typeof devices[0][k] === "number") : [];
      const head = ["Line", "Address", "Health", "Since", "Last success", "Failures in a row",
        ...counts.map((k) => k.replace(/_/g, " ")), "Stout (ms)", "Learnt p99 (ms)",
        "Probe timeout (ms)", "Exceptions", "Upstream"];
      clear(holder).append(devices.length ? el("table", { id: "devices-table" },
        el("thead", {}, el("tr", {}, ...head.map((h) => el("th", { text: h })))),
        el("tbody", {}, ...devices.map((d) => el("tr", { "data-address": d.address,
          "data-line": show(d.line) },
          el("td", { class: "line", text: show(d.line) }),
          el("td", { class: "num", text: d.address }),
          el("td", { class: `health-${d.health}` }, show(d.health),
            d.diagnosis ? el("div", { class: "diagnosis", text: d.diagnosis }) : null),
          el("td", { text: localTime(d.health_since) }),
          el("td", { text: localTime(d.last_success) }),
          el("td", { class: "num", text: show(d.consecutive_failures) }),
          ...counts.map((k) => el("td", { class: "num", text: show(d[k]) })),
          el("td", { class: "num stout", text: ms(d.stout_ms) }),
          el("td", { class: "num learnt-p99", text: ms(d.learnt_p99_ms) }),
          el("td", { class: "num probe-timeout", text: ms(d.probe_timeout_ms) }),
          el("td", { text: show(d.exceptions) }),
          el("td", { text: d.upstream ? `${d.upstream.host} unit ${d.upstream.unit}` : "—" })))))
        : el("p", { id: "no-devices", text: "No device has been asked yet." }));
    },
  };
}

// ---- Scenarios ---------------------------------------------------------------------------

function errorCount(errors) {
  if (!errors || typeof errors !== "object") return show(errors);
  const total = Object.values(errors).reduce((a, b) => a + b, 0);
  return total ? `${total} ${JSON.stringify(errors)}` : "0";
}

function scenariosPage(body) {
  const message = el("p", { id: "scenarios-message" });
  const save = adminControl(el("input", { type: "checkbox", id: "scenario-save" }));
  const table = liveTable("scenarios-table", [
    { label: "Name", get: (s) => s.name, cls: () => "name" },
    { label: "Kind", get: (s) => s.kind },
    { label: "Target", get: (s) => s.target },
    { label: "Function", get: (s) => s.function, num: true },
    { label: "Trigger", get: (s) => s.trigger },
    { label: "State", render: (td, s) => {
      clear(td).append(el("span", { class: `state state-${s.state}`, text: s.state }));
    } },
    { label: "Message", get: (s) => s.message || "", cls: () => "message" },
    { label: "Runs", get: (s) => s.runs, num: true },
    { label: "Successes", get: (s) => s.successes, num: true },
    { label: "Errors", get: (s) => errorCount(s.errors) },
    { label: "Last success", get: (s) => localTime(s.last_success) },
    { label: "Data age", get: (s) => typeof s.data_age_s === "number"
      ? `${s.data_age_s.toFixed(1)} s${s.stale ? " (stale)" : ""}` : "—" },
    { label: "", cls: () => "actions", render: (td, s, isNew) => {
      if (isNew) {
        td.append(
          adminControl(el("button", { type: "button", class: "enable", text: "Enable",
            onclick: () => enableScenario(s.name, true, save.checked, message) })), " ",
          adminControl(el("button", { type: "button", class: "disable", text: "Disable",
            onclick: () => enableScenario(s.name, false, save.checked, message) })));
      }
    } },
  ], (s) => `${s.kind}/${s.name}`);
  const fields = el("textarea", { id: "scenario-test-fields", rows: 6, cols: 50,
    placeholder: "slave = 1\nfunction = 3\naddress = 0\nquantity = 2\ntable = 100" });
  const result = el("pre", { id: "scenario-test-result" });
  const testButton = adminControl(el("button", { type: "button", id: "scenario-test",
    text: "Run the test", onclick: () => testScenario(fields.value, result) }));
  body.append(message,
    el("p", {}, el("label", {}, save, " enable / disable also in the configuration file")),
    table.element,
    el("h2", { text: "Test a scenario" }),
    el("p", { text: "One KEY = VALUE per line, as in a [[scenario]] table of the file." }),
    fields, el("div", { class: "controls" }, testButton), result);
  return {
    async refresh() {
      const data = await load("/api/scenarios");
      if (data) table.update(listOf(data, "scenarios"));
    },
  };
}

async function enableScenario(name, on, save, message) {
  const result = await api("POST",
    `/api/scenarios/${encodeURIComponent(name)}/${on ? "enable" : "disable"}`, { save });
  message.className = result.ok ? "ok" : "error";
  message.textContent = result.ok ? `scenario ${name} ${on ? "enabled" : "disabled"}`
    : refusal(result);
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
  out.textContent = "testing…";
  const result = await api("POST", "/api/scenarios/test", fields);
  out.className = result.ok && !result.data.error ? "" : "error";
  out.textContent = result.ok ? JSON.stringify(result.data, null, 2) : refusal(result);
}

// ---- Exchange table ----------------------------------------------------------------------

function ascii(value) {
  return [value >> 8, value & 0xff]
    .map((b) => (b >= 0x20 && b < 0x7f ? String.fromCharCode(b) : ".")).join("");
}

function tablePage(body) {
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
  const writeResult = el("span", { id: "table-write-result" });
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
      writeResult.className = "field-error";
      writeResult.textContent = "an address and values, in decimal or 0x hex";
      return;
    }
    const result = await api("POST", "/api/table", { address: at, values });
    writeResult.className = result.ok ? "ok" : "field-error";
    writeResult.textContent = result.ok ? `written ${values.length} from ${hex4(at)}`
      : refusal(result);
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
      clear(grid).append(el("table", { id: "table-grid" },
        el("thead", {}, el("tr", {}, el("th", { text: "Address" }),
          el("th", { text: view.value }))),
        el("tbody", {}, ...(data.values || []).map((v, i) => el("tr",
          { "data-address": start + i }, el("th", { text: label(start + i) }),
          el("td", { class: "value mono", text: format(v) }))))));
    },
  };
  return page;
}

// ---- Lines -------------------------------------------------------------------------------

// A remote line's connection figures, after its URL (as mbgw status shows them).
const remoteFigures = (l) => (l.counters && "reconnects" in l.counters
  ? ` (${l.counters.reconnects} reconnects, ${l.counters.stray_replies} stray replies)` : "");

// The daemon's lines, where each face's units go and the remote servers they reach (mbgw
// status's lines, routes and servers).
function linesPage(body) {
  const holder = el("div");
  body.append(holder);
  const table = (id, head, rows) => el("table", { id },
    el("thead", {}, el("tr", {}, ...head.map((h) => el("th", { text: h })))),
    el("tbody", {}, ...rows));
  return {
    async refresh() {
      const s = await load("/api/status");
      if (!s) return;
      const lines = listOf(s, "lines");
      const routes = listOf(s, "routes");
      const servers = listOf(s, "servers");
      clear(holder).append(
        el("h2", { text: "Lines" }),
        lines.length ? table("lines-table", ["Name", "Device", "Mode", "State", "Requests",
          "Replies", "Timeouts", "Devices"], lines.map((l) => el("tr", { "data-line": l.name },
          el("td", { class: "line", text: show(l.name) }),
          el("td", { text: show(l.device) + remoteFigures(l) }),
          el("td", { text: show(l.mode) }),
          el("td", { class: `state-${l.state}`, text: show(l.state) }),
          el("td", { class: "num", text: show(l.requests) }),
          el("td", { class: "num", text: show(l.replies) }),
          el("td", { class: "num", text: show(l.timeouts) }),
          el("td", { class: "num", text: show(listOf(l, "devices").length) }))))
          : el("p", { id: "no-lines", text: "This mode has one line, serial." }),
        el("h2", { text: "Routes" }),
        routes.length ? table("routes-table", ["Face", "Units", "Target", "Rewrite", ""],
          routes.map((r) => el("tr", {},
            el("td", { text: show(r.face) }),
            el("td", { text: show(r.units) }),
            el("td", { text: show(r.target) }),
            el("td", { text: r.rewrite ? show(r.rewrite) : "—" }),
            el("td", { text: r.implicit ? "implicit" : "" }))))
          : el("p", { id: "no-routes", text: "No routes." }),
        ...(servers.length ? [el("h2", { text: "Servers" }),
          table("servers-table", ["Server", "Requests", "Replies", "Exceptions", "Timeouts",
            "Unreachable", "Open", "Opened", "Lost"], servers.map((r) => {
            const c = r.counters || {};
            return el("tr", { "data-server": r.server },
              el("td", { text: show(r.server) }),
              ...[c.requests, c.replies, c.device_exceptions, c.timeouts, c.unreachable,
                listOf(r, "connections").length, c.connections_opened, c.connections_lost]
                .map((n) => el("td", { class: "num", text: show(n) })));
          }))] : []));
    },
  };
}

// ---- Statistics --------------------------------------------------------------------------

function statsPage(body) {
  const message = el("p", { id: "stats-message" });
  const holder = el("div");
  body.append(el("div", { class: "controls" }, adminControl(el("button", {
    type: "button", id: "stats-reset", text: "Reset the counters", onclick: async () => {
      const result = await api("POST", "/api/stats/reset");
      message.className = result.ok ? "ok" : "error";
      message.textContent = result.ok ? "counters reset" : refusal(result);
    } })), message), holder);
  return {
    async refresh() {
      const data = await load("/api/stats");
      if (data) clear(holder).append(factsTable("stats-table", leaves(data, "", [])));
    },
  };
}

// ---- Traffic -----------------------------------------------------------------------------

// The decoded view (the clients' exchanges and the scenarios' runs) or the raw line (its
// bursts in hex, mbgw trace --raw), and the filters of mbgw trace.
const DECODED_COLUMNS = ["Time", "Direction", "Line", "Client", "Unit", "Function", "Length", "PDU",
  "Outcome", "Latency ms"];
const RAW_COLUMNS = ["Time", "Gap µs", "Kind", "Length", "Bytes"];
const TRACE_FILTERS = [["line", "Line"], ["unit", "Unit"], ["client", "Client"],
  ["function", "Function"], ["scenario", "Scenario"]];

function trafficPage(body) {
  const shown = [];                 // the events shown, for the pcap
  let paused = false;
  let skipped = 0;
  let source = null;
  const tbody = el("tbody");
  const headRow = el("tr");
  const info = el("span", { id: "trace-info" });
  const pause = el("button", { type: "button", id: "trace-pause", text: "Pause" });
  const download = el("button", { type: "button", id: "trace-pcap",
    text: "Download the pcap of what was shown" });
  const clearButton = el("button", { type: "button", id: "trace-clear", text: "Clear" });
  const raw = el("input", { type: "checkbox", id: "trace-raw" });
  const errors = el("input", { type: "checkbox", id: "trace-errors" });
  const inputs = TRACE_FILTERS.map(([key]) =>
    el("input", { type: "text", id: `trace-${key}`, size: "8", "data-key": key }));
  const apply = el("button", { type: "button", id: "trace-apply", text: "Apply" });
  body.append(el("div", { class: "controls" }, pause, clearButton, download, info),
    el("div", { class: "controls" },
      el("label", {}, raw, " raw line"),
      ...TRACE_FILTERS.map(([, label], i) => el("label", {}, `${label} `, inputs[i])),
      el("label", {}, errors, " errors only"), apply),
    el("table", { id: "trace-table" }, el("thead", {}, headRow), tbody));

  const say = () => {
    info.textContent = `${shown.length} events shown` +
      (paused ? `, paused (${skipped} not shown)` : "");
  };
  pause.addEventListener("click", () => {
    paused = !paused;
    pause.textContent = paused ? "Resume" : "Pause";
    say();
  });
  clearButton.addEventListener("click", () => { shown.length = 0; clear(tbody); say(); });
  download.addEventListener("click", () => downloadPcap(shown));

  const decodedRow = (event) => el("tr", { class: "trace-event" },
    el("td", { text: typeof event.time === "number" ? clock(event.time) : show(event.time) }),
    el("td", { text: show(event.direction) }),
    el("td", { class: "line", text: show(event.line) }),
    el("td", { class: "peer", text: event.scenario != null ? `scenario ${event.scenario}`
      : show(event.remote) }),
    el("td", { class: "num", text: show(event.unit) }),
    el("td", { class: "num", text: show(event.function) }),
    el("td", { class: "num", text: show(event.length) }),
    el("td", { class: "pdu mono", text: show(event.pdu) }),
    el("td", { text: show(event.outcome) }),
    el("td", { class: "num", text: show(event.latency_ms) }));
  const rawRow = (event) => el("tr", { class: `trace-event raw-${event.kind}` },
    el("td", { text: typeof event.time === "number" ? clock(event.time) : show(event.time) }),
    el("td", { class: "num", text: show(event.gap_us) }),
    el("td", { class: "kind", text: show(event.kind) }),
    el("td", { class: "num", text: show(event.length) }),
    el("td", { class: "bytes mono", text: show(event.bytes) }));

  const start = () => {
    if (source) source.close();
    delete info.dataset.stream;
    shown.length = 0;
    clear(tbody);
    clear(headRow).append(...(raw.checked ? RAW_COLUMNS : DECODED_COLUMNS)
      .map((c) => el("th", { text: c })));
    const query = new URLSearchParams();
    if (raw.checked) query.set("raw", "1");
    if (errors.checked) query.set("errors", "1");
    for (const input of inputs) {
      if (input.value.trim()) query.set(input.dataset.key, input.value.trim());
    }
    const isRaw = raw.checked;
    source = new EventSource(`/api/trace?${query}`);
    source.onmessage = (message) => {
      let event;
      try { event = JSON.parse(message.data); } catch (e) { return; }
      if (!event || !(isRaw ? event.raw : event.direction)) return;   // the stream's header
      if (paused) { skipped += 1; say(); return; }
      shown.push(event);
      if (shown.length > TRACE_KEPT) shown.shift();
      tbody.prepend(isRaw ? rawRow(event) : decodedRow(event));
      while (tbody.children.length > TRACE_ROWS) tbody.lastChild.remove();
      say();
    };
    source.onerror = () => {
      $("page-error").textContent = source.readyState === EventSource.CLOSED
        ? "the trace stream ended (a filter refused?)" : "the trace stream is reconnecting…";
    };
    source.onopen = () => {
      $("page-error").textContent = "";
      info.dataset.stream = "open";
    };
    say();
  };
  raw.addEventListener("change", start);
  errors.addEventListener("change", start);
  apply.addEventListener("click", start);
  start();
  return { leave() { if (source) source.close(); } };
}

function downloadPcap(events) {
  const url = URL.createObjectURL(pcapOf(events));          // pcap.js
  const link = el("a", { href: url, download: "mbgw-trace.pcap" });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

// ---- Configuration -----------------------------------------------------------------------

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

function configPage(body) {
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

// ---- start -------------------------------------------------------------------------------

async function start() {
  $("login-form").addEventListener("submit", logIn);
  $("logout").addEventListener("click", logOut);
  window.addEventListener("hashchange", route);
  const result = await api("GET", "/api/session");
  if (result.ok) loggedIn(result.data);
  else showLogin("");
}

document.addEventListener("DOMContentLoaded", start);
