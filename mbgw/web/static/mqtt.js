// ---- Northbound MQTT's figures (the status's "mqtt"), on the Overview and the Lines page ---
import { el, factsTable, table } from "./dom.js";
import { show } from "./format.js";

// The session and its counts, as a facts table.
export function mqttFacts(id, mqtt) {
  return factsTable(id, [
    ["Broker", `${mqtt.broker} (${mqtt.profile}, node ${mqtt.node})`],
    ["Connected", mqtt.connected ? "yes" : "no"],
    ["Messages sent", String(mqtt.messages_sent)],
    ["Dropped (slow broker)", String(mqtt.messages_dropped)],
    ["Writes", String(mqtt.writes)],
    ["Refused commands", String(mqtt.commands_refused)],
  ]);
}

// Each line's state as the broker last got it (Lines/NAME/State) beside its state here:
// lines, the status's "lines".
export function mqttLines(id, mqtt, lines) {
  const published = mqtt.lines || {};
  const names = [...new Set([...lines.map((l) => l.name), ...Object.keys(published)])];
  return table(id, ["Line", "Topic", "The broker has", "Here"], names.map((name) => {
    const here = lines.find((l) => l.name === name);
    const sent = published[name];
    return el("tr", { "data-line": name },
      el("td", { text: name }),
      el("td", { class: "topic", text: `Lines/${name}/State` }),
      el("td", { class: "published", text: sent === undefined ? "not sent yet" : show(sent) }),
      el("td", { class: "here", text: here ? show(here.state) : "—" }));
  }));
}
