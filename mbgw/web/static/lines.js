// ---- Lines: every line, a page per line (#lines/NAME), the route map and its editing, ------
// ---- the remote servers --------------------------------------------------------------------
import { load } from "./api.js";
import { clear, el, table } from "./dom.js";
import { listOf, show } from "./format.js";
import { lineLoad, linePage } from "./line_page.js";
import { mqttFacts, mqttLines } from "./mqtt.js";
import { routeEditor } from "./route_editor.js";

// A remote line's connection figures, after its URL (as mbgw status shows them).
const remoteFigures = (l) => (l.counters && "reconnects" in l.counters
  ? ` (${l.counters.reconnects} reconnects, ${l.counters.stray_replies} stray replies)` : "");

// A line's read cache over its units (mbgw status's "cache"): "hits / coalesced / misses /
// stale", or a dash for a line whose cache has not served.
function cacheFigures(cache) {
  if (!cache) return "—";
  const sum = { hits: 0, coalesced: 0, misses: 0, stale_served: 0 };
  for (const figures of Object.values(cache.units || {})) {
    for (const key of Object.keys(sum)) sum[key] += figures[key] || 0;
  }
  return `${sum.hits} / ${sum.coalesced} / ${sum.misses} / ${sum.stale_served}`;
}

// "3: 2 up, 1 down"
function health(devices) {
  if (!devices.length) return "0";
  const down = devices.filter((d) => d.health === "down").length;
  const degraded = devices.filter((d) => d.health === "degraded").length;
  return `${devices.length}: ${devices.length - down - degraded} up` +
    (degraded ? `, ${degraded} degraded` : "") + (down ? `, ${down} down` : "");
}

// A row of cells: the first classed cls[0], ...; numbers to the right.
function row(attrs, values, classes) {
  return el("tr", attrs, ...values.map((v, i) => el("td", { class: classes[i] || "", text: v })));
}

const lineLink = (name) => el("a", { href: `#lines/${encodeURIComponent(name)}`, text: name });

// A line's cells in the lines table, as text.
const lineCells = (l) => ["", show(l.device) + remoteFigures(l), show(l.mode), show(l.state),
  show(l.requests), show(l.replies), show(l.timeouts), health(listOf(l, "devices")),
  cacheFigures(l.cache)];

function linesTable(lines) {
  return table("lines-table", ["Name", "Device", "Mode", "State", "Requests", "Replies",
    "Timeouts", "Devices", "Cache hits / coalesced / misses / stale"], lines.map((l) => {
    const tr = row({ "data-line": l.name }, lineCells(l),
      ["line", "", "", `state-${l.state}`, "num", "num", "num", "num", "num cache"]);
    tr.firstChild.append(lineLink(l.name));
    return tr;
  }));
}

// node's content replaced by make() only when key changed: a table a test or an operator
// is reading stays the same element while its figures do not move.
function rebuilt(node, key, make) {
  if (node.dataset.shown === key) return;
  node.dataset.shown = key;
  clear(node).append(...make());
}

// The route map: which unit of which face goes where, in words.
const faceWords = (face) => (face === "tcp" ? "Modbus TCP" : `line ${face}`);

export function routeMap(id, routes) {
  if (!routes.length) return el("p", { id: id && `no-${id}`, text: "No routes." });
  return table(id, ["From", "Units", "Go to", "Rewrite", ""], routes.map((r) => row(
    { class: r.implicit ? "implicit" : "" },
    [faceWords(r.face), show(r.units), show(r.target), r.rewrite ? show(r.rewrite) : "as is",
      r.implicit ? "implicit" : "the file's"],
    ["face", "units", "target", "rewrite", "origin"])));
}

// A server's cells in the servers table, as text.
function serverCells(r) {
  const c = r.counters || {};
  return [show(r.server), ...[c.requests, c.replies, c.device_exceptions, c.timeouts,
    c.unreachable, listOf(r, "connections").length, c.connections_opened,
    c.connections_lost].map(show)];
}

function serversTable(servers) {
  return table("servers-table", ["Server", "Requests", "Replies", "Exceptions", "Timeouts",
    "Unreachable", "Open", "Opened", "Lost"], servers.map((r) => row(
    { "data-server": show(r.server) }, serverCells(r), ["", ...Array(8).fill("num")])));
}

export function linesPage(body, wanted) {
  const tables = el("div");
  const chooser = el("div", { class: "controls" });
  const page = el("div", { id: "line-page-box" });
  const map = el("div");
  const servers = el("div");
  const mqtt = el("div", { id: "lines-mqtt" });
  let lines = [];
  let before = new Map();            // line -> {time, requests, busy_ms} of the last refresh
  let names = "";
  const roles = () => ({ faces: lines.filter((l) => l.mode === "master").map((l) => l.name),
    targets: lines.filter((l) => l.mode === "slave").map((l) => l.name) });
  const editor = routeEditor(roles);
  let editing = false;               // the editor is loaded once the lines are known
  body.append(el("h2", { text: "Lines" }), tables, chooser, page,
    el("h2", { text: "Route map: which unit goes where" }), map, editor.element, servers,
    mqtt);
  return {
    async refresh() {
      const s = await load("/api/status");
      if (!s) return;
      const now = Date.now() / 1000;
      lines = listOf(s, "lines");
      const routes = listOf(s, "routes");
      const loads = lines.map((l) => lineLoad(l, before.get(l.name), now));
      before = new Map(lines.map((l) => [l.name, { time: now, requests: l.requests,
        busy_ms: l.busy_ms }]));
      rebuilt(tables, JSON.stringify(lines.map((l) => [l.name, ...lineCells(l)])),
        () => [lines.length ? linesTable(lines)
        : el("p", { id: "no-lines", text: "This mode has one line, serial." })]);
      const shown = lines.find((l) => l.name === wanted) || lines[0];
      if (lines.map((l) => l.name).join() !== names) {
        names = lines.map((l) => l.name).join();
        const select = el("select", { id: "line-select", onchange: () => {
          location.hash = `#lines/${encodeURIComponent(select.value)}`;
        } }, ...lines.map((l) => el("option", { value: l.name, text: l.name,
          selected: l === shown })));
        clear(chooser).append(...(lines.length ? [el("label", {}, "Show line ", select)] : []));
      }
      clear(page).append(...(shown ? [linePage(shown, loads[lines.indexOf(shown)], routes,
        (rows) => routeMap(null, rows))] : []));
      rebuilt(map, JSON.stringify(routes), () => [routeMap("routes-table", routes)]);
      const remote = listOf(s, "servers");
      rebuilt(servers, JSON.stringify(remote.map(serverCells)), () => (remote.length
        ? [el("h2", { text: "Servers" }), serversTable(remote)] : []));
      clear(mqtt).append(...(s.mqtt ? [el("h2", { text: "MQTT" }),
        mqttFacts("lines-mqtt-facts", s.mqtt), mqttLines("lines-mqtt-table", s.mqtt, lines)]
        : []));
      if (!editing && lines.length) {
        editing = true;
        editor.reload();
      }
    },
  };
}
