// ---- Overview: the front panel, what is wrong since when, the gateway's facts -------------
import { load } from "./api.js";
import { clear, el, factsTable } from "./dom.js";
import { duration, isoTime, show, when } from "./format.js";
import { otherBlocks } from "./blocks.js";
import { mqttFacts } from "./mqtt.js";

const ERROR_COUNTERS = ["timeouts", "crc_errors", "invalid_frames", "gateway_exceptions",
  "echo_errors", "unreachable", "wrong_unit", "wrong_function", "frame_errors", "overruns"];
const ACTIVITY_COUNTERS = ["requests", "replies", "frames_stored", "frames_sent",
  "bytes_received"];
// The status keys this page shows itself; any other block is shown as it comes.
const SHOWN = new Set(["location", "mode", "version", "serial", "uptime_s", "started",
  "line_utilisation_pct", "line_load_pct", "listening", "upstream", "table", "transparent",
  "web", "clients", "devices", "scenarios", "counters", "counters_since", "lines", "routes",
  "servers", "firewall", "tls", "mqtt"]);

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

// "12.0 % (10 s), 8.1 % (1 min), 7.9 % on average": the line's load now and since the reset.
function lineLoad(s) {
  const load = s.line_load_pct || {};
  const now = [["10s", "10 s"], ["1min", "1 min"]].filter(([k]) => typeof load[k] === "number")
    .map(([k, label]) => `${load[k]} % (${label}), `).join("");
  return `${now}${s.line_utilisation_pct} % on average`;
}

// "2 up, 1 down": how many items have each value of a field.
const lineList = (s) => (Array.isArray(s.lines) ? s.lines : []);

// Without line serial: "up" while every line is, else the first other state.
function linesState(s) {
  const other = lineList(s).find((l) => l.state !== "up");
  return other ? other.state : "up";
}

function tally(items, field) {
  if (!items.length) return "none";
  const counts = new Map();
  for (const item of items) counts.set(item[field], (counts.get(item[field]) || 0) + 1);
  return [...counts].map(([value, n]) => `${n} ${value}`).join(", ");
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
      out.push(`Device ${d.address} is ${d.health} since ${when(d.health_since)}` +
        (typeof d.last_success === "number" ? ` (last answer ${isoTime(d.last_success)}).`
          : " (it never answered)."));
    }
  }
  for (const sc of s.scenarios || []) {
    if (sc.state === "error") {
      out.push(`Scenario ${sc.name} is in error: ${sc.message || "?"}` +
        (typeof sc.last_success === "number" ? ` (last success ${isoTime(sc.last_success)}).`
          : " (never succeeded)."));
    } else if (sc.stale) {
      out.push(`Scenario ${sc.name}'s data is stale (${show(sc.data_age_s)} s old).`);
    }
  }
  const persist = (s.table || {}).persist || {};
  if (persist.failing) {
    out.push(`The exchange table is not kept since ${isoTime(persist.failing_since)}: ` +
      `${persist.failing}.`);
  }
  return out;
}

export function overviewPage(body) {
  const facts = el("div");
  const more = el("div", { id: "overview-more" });
  const panelLeds = {
    line: led("led-line", "Line"),
    activity: led("led-activity", "Activity"),
    errors: led("led-errors", "Errors"),
    scenarios: led("led-scenarios", "Scenario errors"),
    devices: led("led-devices", "Devices down"),
  };
  const wrong = el("ul", { id: "overview-wrong" });
  const mqtt = el("div", { id: "overview-mqtt" });
  body.append(el("div", { class: "panel", id: "front-panel" },
    ...Object.values(panelLeds).map((l) => l.node)),
    el("h2", { text: "What is wrong, since when" }), wrong,
    el("h2", { text: "Gateway" }), facts, mqtt, more);
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
        : [["Lines", lineList(s).map((l) => l.name).join(", ")]];
      clear(facts).append(factsTable("overview-facts", [
        ["Location", s.location], ["Mode", s.mode], ["Version", s.version],
        ...line, ["Line state", serial.state], ["Uptime", duration(s.uptime_s)],
        ["Started", isoTime(s.started)],
        ["Line load", typeof s.line_utilisation_pct === "number"
          ? lineLoad(s) : "—"],
        ["Listening", listening(s)],
        ...(Array.isArray(s.clients) ? [["Clients", String(s.clients.length)]] : []),
        ["Devices", tally(s.devices || [], "health")],
        ["Scenarios", tally(s.scenarios || [], "state")],
        ["Counters since", when(s.counters_since)],
      ]));
      clear(mqtt).append(...(s.mqtt ? [el("h2", { text: "MQTT" }),
        mqttFacts("overview-mqtt-facts", s.mqtt)] : []));
      clear(more).append(...otherBlocks(s, SHOWN));
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
