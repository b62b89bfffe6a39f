// The JSON API (/api/...): every call, the session it carries, and a failure in words.

export const session = { role: null, csrf: null };

let sessionGone = () => {};

// What to do when the gateway answers 401 to a logged-in page (the session expired).
export function onSessionGone(handler) { sessionGone = handler; }

// {ok, status, data}; data.error says why when not ok.
export async function api(method, path, body) {
  const headers = { "Accept": "application/json" };
  const options = { method, headers, credentials: "same-origin" };
  if (typeof body === "string") {                // a file's text, as it is
    headers["Content-Type"] = "text/plain; charset=utf-8";
    options.body = body;
  } else if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    options.body = JSON.stringify(body);
  }
  if (method !== "GET" && session.csrf) headers["X-CSRF-Token"] = session.csrf;
  let response;
  try {
    response = await fetch(path, options);
  } catch (err) {
    return { ok: false, status: 0, data: { error: "the gateway does not answer" } };
  }
  let data = null;
  if ((response.headers.get("Content-Type") || "").includes("json")) {
    data = await response.json().catch(() => null);
  }
  if (!response.ok && !(data && data.error)) {
    data = { ...(data || {}), error: `${response.status} ${response.statusText}` };
  }
  if (response.status === 401 && path !== "/api/login" && session.role) sessionGone();
  return { ok: response.ok, status: response.status, data: data || {} };
}

// Why a request failed, in words (the user role is told it only reads).
export function refusal(result) {
  if (result.status === 403 && session.role !== "admin") {
    return `refused: ${result.data.error} (the user role only reads)`;
  }
  return result.data.error;
}

// GET a page's data; on failure the page's error line says why (and the page keeps its last).
export async function load(path) {
  const result = await api("GET", path);
  document.getElementById("page-error").textContent = result.ok ? "" : result.data.error;
  return result.ok ? result.data : null;
}
