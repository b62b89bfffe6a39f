// ---- Lines: the daemon's lines, where each face's units go, the remote servers ------------
import { load } from "./api.js";
import { block } from "./blocks.js";
import { clear, el, table } from "./dom.js";
import { listOf, show } from "./format.js";

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

// Each line's whole status (settings, state, load, devices, timing) on demand; the ones
// opened stay open across the refreshes.
function lineDetails(lines, open) {
  return lines.map((l) => {
    const details = el("details", { "data-line": l.name, open: open.has(l.name) },
      el("summary", { text: `Line ${show(l.name)}: ${show(l.device)}, ${show(l.mode)} mode, ` +
        `${show(l.state)}` }), block(`lines.${l.name}`, l));
    details.addEventListener("toggle", () => {
      if (details.open) open.add(l.name); else open.delete(l.name);
    });
    return details;
  });
}

// A row of cells: the first classed cls[0], ...; numbers to the right.
function row(attrs, values, classes) {
  return el("tr", attrs, ...values.map((v, i) => el("td", { class: classes[i] || "", text: v })));
}

export function linesPage(body) {
  const tables = el("div");
  const details = el("div", { id: "line-details" });
  const open = new Set();
  let shown = "";                   // what the tables show: rebuilt only when it changes
  body.append(tables, details);
  return {
    async refresh() {
      const s = await load("/api/status");
      if (!s) return;
      const lines = listOf(s, "lines");
      const lineRows = lines.map((l) => [show(l.name), show(l.device) + remoteFigures(l),
        show(l.mode),
        show(l.state), show(l.requests), show(l.replies), show(l.timeouts),
        health(listOf(l, "devices")), cacheFigures(l.cache)]);
      const routeRows = listOf(s, "routes").map((r) => [show(r.face), show(r.units),
        show(r.target), r.rewrite ? show(r.rewrite) : "—", r.implicit ? "implicit" : ""]);
      const serverRows = listOf(s, "servers").map((r) => {
        const c = r.counters || {};
        return [show(r.server), ...[c.requests, c.replies, c.device_exceptions, c.timeouts,
          c.unreachable, listOf(r, "connections").length, c.connections_opened,
          c.connections_lost].map(show)];
      });
      clear(details).append(...lineDetails(lines, open));
      const now = JSON.stringify([lineRows, routeRows, serverRows]);
      if (now === shown) return;
      shown = now;
      clear(tables).append(
        el("h2", { text: "Lines" }),
        lineRows.length ? table("lines-table", ["Name", "Device", "Mode", "State", "Requests",
          "Replies", "Timeouts", "Devices", "Cache hits / coalesced / misses / stale"],
        lineRows.map((values, i) => row({ "data-line": lines[i].name }, values,
          ["line", "", "", `state-${lines[i].state}`, "num", "num", "num", "num",
            "num cache"])))
          : el("p", { id: "no-lines", text: "This mode has one line, serial." }),
        el("h2", { text: "Routes" }),
        routeRows.length ? table("routes-table", ["Face", "Units", "Target", "Rewrite", ""],
          routeRows.map((values) => row({}, values, [])))
          : el("p", { id: "no-routes", text: "No routes." }),
        ...(serverRows.length ? [el("h2", { text: "Servers" }),
          table("servers-table", ["Server", "Requests", "Replies", "Exceptions", "Timeouts",
            "Unreachable", "Open", "Opened", "Lost"], serverRows.map((values) => row(
            { "data-server": values[0] }, values, ["", ...Array(8).fill("num")])))] : []));
    },
  };
}
