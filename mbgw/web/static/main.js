// The mbgw web console: one page, hash routes, ES modules over the JSON API (/api/...), one
// module per page.  No build step and no outside asset (plants have no internet).
import { api, onSessionGone, session } from "./api.js";
import { $, clear } from "./dom.js";
import { overviewPage } from "./overview.js";
import { clientsPage } from "./clients.js";
import { devicesPage } from "./devices.js";
import { scenariosPage } from "./scenarios.js";
import { tablePage } from "./table.js";
import { linesPage } from "./lines.js";
import { statsPage } from "./stats.js";
import { trafficPage } from "./traffic.js";
import { configPage } from "./config.js";
import { eventsPage } from "./events.js";
import { firewallPage } from "./firewall.js";
import { adminPage } from "./admin.js";

const POLL_MS = 1000;            // live pages refresh once a second

let current = null;              // the page shown: {refresh, leave}
let timer = null;

// ---- log in / out ------------------------------------------------------------------------

function showLogin(message) {
  session.role = session.csrf = null;
  leavePage();
  $("nav").hidden = $("who").hidden = $("page").hidden = true;
  $("login-page").hidden = false;
  $("login-error").textContent = message || "";
  $("login-password").value = "";
  $("login-password").focus();
}

function loggedIn(data) {
  session.role = data.role;
  session.csrf = data.csrf;
  document.body.dataset.role = data.role;
  $("login-page").hidden = true;
  $("nav").hidden = $("who").hidden = $("page").hidden = false;
  $("role").textContent = data.role;
  route();
}

async function logIn(event) {
  event.preventDefault();
  const result = await api("POST", "/api/login",
    { user: $("login-user").value, password: $("login-password").value });
  if (result.ok) {
    loggedIn(result.data);
  } else {
    $("login-password").value = "";
    $("login-error").textContent = result.status === 429
      ? `Too many attempts: wait a minute. (${result.data.error})`
      : result.status === 401 ? "Wrong user or password." : result.data.error;
  }
}

async function logOut() {
  await api("POST", "/api/logout");
  showLogin("Logged out.");
}

// ---- pages -------------------------------------------------------------------------------

const pages = {
  overview: { title: "Overview", build: overviewPage },
  clients: { title: "Clients", build: clientsPage },
  devices: { title: "Devices", build: devicesPage },
  scenarios: { title: "Scenarios", build: scenariosPage },
  table: { title: "Exchange table", build: tablePage },
  lines: { title: "Lines", build: linesPage },
  stats: { title: "Statistics", build: statsPage },
  traffic: { title: "Traffic", build: trafficPage },
  config: { title: "Configuration", build: configPage },
  firewall: { title: "Firewall", build: firewallPage },
  events: { title: "Events", build: eventsPage },
  admin: { title: "Administration", build: adminPage },
};

function leavePage() {
  if (timer !== null) clearInterval(timer);
  timer = null;
  if (current && current.leave) current.leave();
  current = null;
}

function route() {
  if (!session.role) return;
  // "#lines/meters": the page, then what it shows (a page of its own: one line's)
  const [wanted, ...rest] = location.hash.slice(1).split("/");
  const name = Object.hasOwn(pages, wanted) ? wanted : "overview";
  leavePage();
  for (const link of document.querySelectorAll("nav a")) {
    link.classList.toggle("current", link.getAttribute("href") === "#" + name);
  }
  $("page-title").textContent = pages[name].title;
  $("page-error").textContent = "";
  const body = clear($("page-body"));
  body.dataset.page = name;
  current = pages[name].build(body, decodeURIComponent(rest.join("/")));
  if (current.refresh) {
    let busy = false;
    const tick = async () => {
      if (busy) return;
      busy = true;
      try { await current.refresh(); } finally { busy = false; }
    };
    tick();
    if (current.live !== false) timer = setInterval(tick, POLL_MS);
  }
}

// ---- start -------------------------------------------------------------------------------

async function start() {
  $("login-form").addEventListener("submit", logIn);
  $("logout").addEventListener("click", logOut);
  window.addEventListener("hashchange", route);
  const result = await api("GET", "/api/session");
  if (result.ok) loggedIn(result.data);
  else showLogin("");
}

onSessionGone(() => showLogin("The session has expired: log in again."));
start();
