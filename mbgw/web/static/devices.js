// ---- Devices: one compact row per address, its details on demand --------------------------
import { load } from "./api.js";
import { block } from "./blocks.js";
import { clear, el, scrollBox } from "./dom.js";
import { ago, isoTime, listOf, ms, show } from "./format.js";

// The latency (ms) under which a share of the answers came, from the histogram's buckets.
export function percentile(buckets, share) {
  const entries = Object.entries(buckets || {});
  const total = entries.reduce((n, [, count]) => n + count, 0);
  if (!total) return null;
  let seen = 0;
  for (const [bound, count] of entries) {
    seen += count;
    if (seen >= share * total) return bound === "+Inf" ? Infinity : Number(bound);
  }
  return null;
}

function latency(bound) {
  if (bound === null) return "—";
  return bound === Infinity ? "over the last bucket" : `≤ ${ms(bound)}`;
}

const HEAD = ["Line", "Address", "Health", "Since", "Last answer", "p50", "p99", "Failures",
  "Next probe", "Stout (ms)", "Learnt p99 (ms)", "Probe timeout (ms)", ""];

// The demotion's timing (ms, one decimal, as mbgw status prints it).
const timing = (value) => (typeof value === "number" ? value.toFixed(1) : "—");

export function devicesPage(body) {
  const holder = el("div");
  const open = new Set();            // the rows whose details are shown
  body.append(holder);
  const page = {
    async refresh() {
      const data = await load("/api/devices");
      if (!data) return;
      const devices = listOf(data, "devices");
      if (!devices.length) {
        clear(holder).append(el("p", { id: "no-devices", text: "No device has been asked yet." }));
        return;
      }
      const rows = [];
      for (const d of devices) {
        const key = `${show(d.line)}/${d.address}`;
        const toggle = el("button", { type: "button", class: "details",
          text: open.has(key) ? "Less" : "Details", onclick: () => {
            if (open.has(key)) open.delete(key); else open.add(key);
            page.refresh();
          } });
        rows.push(el("tr", { "data-address": d.address, "data-line": show(d.line) },
          el("td", { class: "line", text: show(d.line) }),
          el("td", { class: "num", text: d.address }),
          el("td", { class: `health-${d.health}` }, show(d.health),
            d.diagnosis ? el("div", { class: "diagnosis", text: d.diagnosis }) : null),
          el("td", { text: ago(d.health_since), title: isoTime(d.health_since) }),
          el("td", { text: typeof d.last_success === "number" ? ago(d.last_success) : "never",
            title: isoTime(d.last_success) }),
          el("td", { class: "num", text: latency(percentile(d.latency_buckets_ms, 0.5)) }),
          el("td", { class: "num", text: latency(percentile(d.latency_buckets_ms, 0.99)) }),
          el("td", { class: "num", text: show(d.consecutive_failures) }),
          el("td", { text: typeof d.next_probe_in_s === "number"
            ? `in ${d.next_probe_in_s.toFixed(1)} s` : "—" }),
          el("td", { class: "num stout", text: timing(d.stout_ms) }),
          el("td", { class: "num learnt-p99", text: timing(d.learnt_p99_ms) }),
          el("td", { class: "num probe-timeout", text: timing(d.probe_timeout_ms) }),
          el("td", { class: "actions" }, toggle)));
        if (open.has(key)) {
          rows.push(el("tr", { class: "device-details", "data-details": key },
            el("td", { colspan: HEAD.length }, block(`device ${key}`, d))));
        }
      }
      clear(holder).append(scrollBox(el("table", { id: "devices-table" },
        el("thead", {}, el("tr", {}, ...HEAD.map((h) => el("th", { text: h })))),
        el("tbody", {}, ...rows))));
    },
  };
  return page;
}
