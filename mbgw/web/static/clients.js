// ---- Clients: every Modbus TCP connection (the slave mode's listeners, the table server) ---
import { act, confirmed } from "./actions.js";
import { load } from "./api.js";
import { adminControl, el, liveTable } from "./dom.js";
import { ago, isoTime, listOf } from "./format.js";

export function clientsPage(body) {
  const message = el("p", { id: "clients-message", class: "result" });
  const table = liveTable("clients-table", [
    { label: "ID", get: (c) => c.id, num: true },
    { label: "Address", get: (c) => c.peer, cls: () => "peer" },
    { label: "Listener", get: (c) => c.listener },
    { label: "Role", get: (c) => c.role },
    { label: "Connected since", get: (c) => isoTime(c.connected_since) },
    { label: "Requests", get: (c) => c.requests, num: true },
    { label: "In flight", get: (c) => c.in_flight, num: true },
    { label: "Last activity", get: (c) => ago(c.last_activity) },
    { label: "", cls: () => "actions", render: (td, c, isNew) => {
      if (!isNew) return;
      td.append(adminControl(el("button", { type: "button", class: "close-client",
        text: "Close", onclick: () => closeClient(c, message) })));
    } },
  ], (c) => `${c.listener}/${c.id}`);     // the face's and the table's ids may meet
  body.append(message, table.element);
  return {
    async refresh() {
      const data = await load("/api/clients");
      if (data) table.update(listOf(data, "clients"));
    },
  };
}

function closeClient(c, message) {
  if (!confirmed(`Close the connection of ${c.peer} (client ${c.id})? A SCADA link ` +
    "reconnects on its own, but its requests under way are lost.")) return;
  act(message, "POST", `/api/clients/${encodeURIComponent(c.id)}/close`, undefined,
    `client ${c.id} closed`);
}
