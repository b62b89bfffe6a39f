// Every action's outcome shown one way: "working…", then the success in green or the
// refusal in red, in the element the page keeps for it.
import { api, refusal } from "./api.js";

// The API call's result; out says "done" (a string, or done(data) -> string) or why not.
export async function act(out, method, path, body, done) {
  out.className = "result";
  out.textContent = "working…";
  const result = await api(method, path, body);
  out.className = result.ok ? "result ok" : "result error";
  out.textContent = result.ok ? (typeof done === "function" ? done(result.data) : done)
    : refusal(result);
  return result;
}

// A question before an action that cuts something off (a client, the counters, the file).
export function confirmed(question) {
  return window.confirm(question);
}
