// ---- Lines: the daemon's lines, where each face's units go, the remote servers ------------
import { load } from "./api.js";
import { clear, el, table } from "./dom.js";
import { listOf, show } from "./format.js";

export function linesPage(body) {
  const holder = el("div");
  body.append(holder);
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
          el("td", { text: show(l.device) }),
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

