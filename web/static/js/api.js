// The JSON API client: the token kept in the browser, errors turned into words.

const TOKEN_KEY = "handful.token";
const USER_KEY = "handful.user";

export function session() {
  const token = sessionStorage.getItem(TOKEN_KEY) || localStorage.getItem(TOKEN_KEY);
  const user = sessionStorage.getItem(USER_KEY) || localStorage.getItem(USER_KEY);
  return token ? { token, user: user ? JSON.parse(user) : null } : null;
}

export function saveSession(token, user, remember) {
  clearSession();
  const store = remember ? localStorage : sessionStorage;
  store.setItem(TOKEN_KEY, token);
  store.setItem(USER_KEY, JSON.stringify(user));
}

export function clearSession() {
  for (const s of [localStorage, sessionStorage]) {
    s.removeItem(TOKEN_KEY);
    s.removeItem(USER_KEY);
  }
}

/** An error from the API, with the words to show and, for 422s, one message per field. */
export class ApiError extends Error {
  constructor(status, message, fields) {
    super(message);
    this.status = status;
    this.fields = fields || {};
  }
}

function fieldName(loc) {
  // FastAPI's loc is like ["body", "limits", "max_step_pa"]: the last named part is the field.
  const parts = (loc || []).filter((p) => typeof p === "string" && p !== "body" && p !== "query");
  return parts.length ? parts[parts.length - 1] : "";
}

export function describeError(status, body) {
  const detail = body && body.detail !== undefined ? body.detail : body;
  if (Array.isArray(detail)) {
    const fields = {};
    const lines = detail.map((d) => {
      const f = fieldName(d.loc);
      const msg = d.msg || JSON.stringify(d);
      if (f) fields[f] = fields[f] ? `${fields[f]}; ${msg}` : msg;
      return f ? `${f}: ${msg}` : msg;
    });
    return new ApiError(status, lines.join("\n"), fields);
  }
  if (typeof detail === "string" && detail) {
    // Service errors read "<field>: <what is wrong>"; keep the field so a form can place it.
    const m = /^([a-z_]+): (.+)$/s.exec(detail);
    return new ApiError(status, detail, m ? { [m[1]]: m[2] } : {});
  }
  if (status === 401) return new ApiError(status, "You are not logged in (or your session expired).");
  if (status === 403) return new ApiError(status, "Your role may not do this.");
  return new ApiError(status, `The server answered ${status}${detail ? ": " + JSON.stringify(detail) : ""}.`);
}

/**
 * Call the API. Returns parsed JSON (or text for non-JSON answers); throws ApiError with words.
 * opts: {body, headers, raw (return the Response), noAuthRedirect}
 */
export async function api(method, path, opts = {}) {
  const headers = { Accept: "application/json", ...(opts.headers || {}) };
  const s = session();
  if (s) headers.Authorization = `Bearer ${s.token}`;
  let body;
  if (opts.body !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(opts.body);
  }
  let response;
  try {
    response = await fetch(path, { method, headers, body });
  } catch (err) {
    throw new ApiError(0, `Cannot reach the server (${err.message}). Is it running?`);
  }
  if (opts.raw && response.ok) return response;
  const type = response.headers.get("Content-Type") || "";
  let payload = null;
  if (type.includes("application/json")) {
    try { payload = await response.json(); } catch { payload = null; }
  } else {
    payload = await response.text();
  }
  if (!response.ok) {
    if (response.status === 401 && !opts.noAuthRedirect) {
      clearSession();
      location.href = `/login?next=${encodeURIComponent(location.pathname)}`;
    }
    throw describeError(response.status, payload);
  }
  return payload;
}

/** A fresh idempotency key (works on plain-http lab hosts, where crypto.randomUUID may be absent). */
export function newIdempotencyKey() {
  if (globalThis.crypto && crypto.randomUUID) return crypto.randomUUID();
  const bytes = new Uint8Array(16);
  crypto.getRandomValues(bytes);
  return Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
}
