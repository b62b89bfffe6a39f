// ---- Events: what the journal got, newest first (device up/down, scenario errors, ...) -----
import { load } from "./api.js";
import { el, liveTable } from "./dom.js";
import { ago, isoTime, listOf } from "./format.js";

const KINDS = ["", "device-down", "device-up", "scenario-error", "connection-refused",
  "firewall-refused", "tls-refused", "login-ok", "login-failed", "config-changed",
  "client-closed", "counters-reset"];

export function eventsPage(body) {
  const kind = el("select", { id: "events-kind" },
    ...KINDS.map((k) => el("option", { value: k, text: k || "every event" })));
  const table = liveTable("events-table", [
    { label: "Time", get: (e) => `${isoTime(e.time)} (${ago(e.time)})`, cls: () => "time" },
    { label: "Event", get: (e) => e.event, cls: (e) => `event level-${e.level}` },
    { label: "Message", get: (e) => e.message, cls: () => "message" },
  ], (e) => e.key);
  body.append(el("div", { class: "controls" }, el("label", {}, "Show ", kind)), table.element);
  const page = {
    async refresh() {
      const data = await load("/api/events");
      if (!data) return;
      const events = listOf(data, "events").filter((e) => !kind.value || e.event === kind.value);
      for (const e of events) e.key = `${e.time}/${e.event}/${e.message}`;
      table.update(events);
    },
  };
  kind.addEventListener("change", () => page.refresh());
  return page;
}
