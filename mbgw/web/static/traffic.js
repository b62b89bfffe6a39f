// ---- Traffic: the live trace (decoded or the raw line), its filters, the pcap -------------
// The decoded view (the clients' exchanges and the scenarios' runs) or the raw line (its
// bursts in hex, mbgw trace --raw), and the filters of mbgw trace.
import { $, clear, el, scrollBox } from "./dom.js";
import { clock, ms, show } from "./format.js";
import { pcapOf } from "./pcap.js";

const TRACE_ROWS = 500;          // rows the Traffic page keeps on screen
const TRACE_KEPT = 20000;        // events kept for the pcap download (the oldest go first)

const DECODED_COLUMNS = ["Time", "Direction", "Line", "Client", "Unit", "Function", "Length", "PDU",
  "Outcome", "Latency"];
const RAW_COLUMNS = ["Time", "Gap µs", "Kind", "Length", "Bytes"];
const TRACE_FILTERS = [["line", "Line"], ["unit", "Unit"], ["client", "Client"],
  ["function", "Function"], ["scenario", "Scenario"]];

export function trafficPage(body) {
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
  const find = el("input", { type: "search", id: "trace-find", size: "12" });
  body.append(el("div", { class: "controls" }, pause, clearButton, download, info),
    el("div", { class: "controls" },
      el("label", {}, raw, " raw line"),
      ...TRACE_FILTERS.map(([, label], i) => el("label", {}, `${label} `, inputs[i])),
      el("label", {}, errors, " errors only"), apply),
    el("div", { class: "controls" }, el("label", {}, "Show only rows with ", find)),
    scrollBox(el("table", { id: "trace-table" }, el("thead", {}, headRow), tbody)));
  // the rows on screen narrowed by a text (a unit, an address, a byte): no new stream
  const matches = (tr) => !find.value.trim() ||
    tr.textContent.toLowerCase().includes(find.value.trim().toLowerCase());
  find.addEventListener("input", () => {
    for (const tr of tbody.children) tr.hidden = !matches(tr);
  });

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
    el("td", { class: "num", text: ms(event.latency_ms) }));
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
      const row = isRaw ? rawRow(event) : decodedRow(event);
      row.hidden = !matches(row);
      tbody.prepend(row);
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

