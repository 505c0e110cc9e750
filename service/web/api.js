// The service API with the token from this tab's sessionStorage. The token only ever travels in the
// Authorization header: never in a URL, never in a log.

const KEY = "holo.token";

export const token = {
  get: () => sessionStorage.getItem(KEY),
  set: (t) => sessionStorage.setItem(KEY, t),
  clear: () => sessionStorage.removeItem(KEY),
};

export class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.status = status;
  }
}

let onUnauthorized = () => {};
export function setUnauthorizedHandler(fn) { onUnauthorized = fn; }

function headers(extra = {}, tok = token.get()) {
  const h = new Headers(extra);
  if (tok) h.set("Authorization", `Bearer ${tok}`);
  return h;
}

async function problem(resp) {
  let detail = `${resp.status} ${resp.statusText}`;
  try {
    const body = await resp.json();
    if (body && typeof body.detail === "string") detail = body.detail;
    else if (body && Array.isArray(body.detail)) {
      detail = body.detail.map((e) => `${(e.loc || []).join(".")}: ${e.msg}`).join("; ");
    }
  } catch (_) { /* not JSON */ }
  return new ApiError(resp.status, detail);
}

// fetch with the token; answers the Response, or throws ApiError for a non-2xx answer.
export async function request(path, { method = "GET", body, json, tok, signal, accept } = {}) {
  const extra = {};
  if (json !== undefined) { extra["Content-Type"] = "application/json"; body = JSON.stringify(json); }
  if (accept) extra["Accept"] = accept;
  const sent = tok || token.get();
  const resp = await fetch(path, { method, body, signal, headers: headers(extra, tok), credentials: "omit",
                                   redirect: "error", referrerPolicy: "no-referrer" });
  if (!resp.ok) {
    const err = await problem(resp);
    // Only the session's own token being refused signs the tab out: a request sent without a token (a timer
    // that fired after signing out) or with an earlier one must not sign out the session that came after it.
    if (resp.status === 401 && !tok && sent && sent === token.get()) onUnauthorized(err);
    throw err;
  }
  return resp;
}

export async function getJSON(path, opts) { return (await request(path, opts)).json(); }
export async function postJSON(path, json, opts = {}) { return (await request(path, { ...opts, method: "POST", json })).json(); }

// A file of the API as an object URL (for <img src> and downloads, which cannot send a header).
export async function blobURL(path, opts) {
  const resp = await request(path, opts);
  return URL.createObjectURL(await resp.blob());
}

// Server-sent events over fetch (EventSource cannot send an Authorization header): calls onEvent(name, data)
// for each event until the stream ends or `signal` aborts.
export async function streamEvents(path, onEvent, signal) {
  const resp = await request(path, { signal, accept: "text/event-stream" });
  const reader = resp.body.pipeThrough(new TextDecoderStream()).getReader();
  let buf = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buf += value.replace(/\r\n?/g, "\n");
    let cut;
    while ((cut = buf.indexOf("\n\n")) >= 0) {
      const block = buf.slice(0, cut);
      buf = buf.slice(cut + 2);
      let name = "message";
      const data = [];
      for (const line of block.split("\n")) {
        if (line.startsWith(":")) continue;
        const i = line.indexOf(":");
        const field = i < 0 ? line : line.slice(0, i);
        const v = i < 0 ? "" : line.slice(i + 1).replace(/^ /, "");
        if (field === "event") name = v;
        else if (field === "data") data.push(v);
      }
      if (!data.length) continue;
      let parsed;
      try { parsed = JSON.parse(data.join("\n")); } catch (_) { continue; }
      onEvent(name, parsed);
    }
  }
}
