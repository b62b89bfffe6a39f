// Building the pages.  Every value from the gateway is inserted as text (textContent /
// createTextNode), never as markup: a client's address, a scenario's name or a trace payload
// cannot inject anything.
import { session } from "./api.js";
import { show } from "./format.js";

// el("td", {class: "num", text: 42}, child...): an element; "text" is set as textContent,
// on* entries are listeners, booleans are properties (disabled, checked), the rest attributes.
export function el(tag, props, ...children) {
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

export function $(id) { return document.getElementById(id); }

export function clear(node) {
  while (node.firstChild) node.removeChild(node.firstChild);
  return node;
}

// An admin's control: disabled for the user role (the API refuses it anyway).
export function adminControl(node) {
  if (session.role !== "admin") {
    node.disabled = true;
    node.title = "admin only";
  }
  node.classList.add("admin-only");
  return node;
}

// A wide table scrolls sideways in its own box, never the page (a phone's 390 px).
export function scrollBox(table) {
  return el("div", { class: "scroll" }, table);
}

// A table with a head row: head a list of labels, rows its <tr>s.
export function table(id, head, rows) {
  return scrollBox(el("table", { id },
    el("thead", {}, el("tr", {}, ...head.map((h) => el("th", { text: h })))),
    el("tbody", {}, ...rows)));
}

// A table whose rows are kept by key across refreshes (a button being clicked stays the same
// element).  columns: [{label, get(item) -> value, cls(item) -> class, num, render(td, item,
// isNew)}].
export function liveTable(id, columns, key) {
  const rows = new Map();
  const tbody = el("tbody");
  const head = el("table", { id }, el("thead", {}, el("tr", {},
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
  return { element: el("div", {}, scrollBox(head), empty), update };
}

// Rows [name, value] or [name, value, label] as a two-column table (rebuilt: nothing in it
// is clicked); data-name is the name, the head cell shows the label when there is one.
export function factsTable(id, rows) {
  return scrollBox(el("table", { id, class: "facts" }, el("tbody", {},
    ...rows.map(([name, value, label]) =>
      el("tr", { "data-name": name }, el("th", { text: label || name }),
         el("td", { class: typeof value === "number" ? "num" : "", text: show(value) }))))));
}
