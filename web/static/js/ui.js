// Page helpers: login gate, role gating, formatting, inline errors, downloads.
import { api, clearSession, session } from "./api.js";

export const CHAMBER_NAMES = [0, 1, 2].flatMap((j) =>
  ["x", "y"].flatMap((a) => ["+", "−"].map((s) => `j${j}.${a}${s}`)));

export function $(sel, root = document) { return root.querySelector(sel); }

/** Make an element: el("td", {class: "x", onclick}, "text", child, ...). */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
    else if (k === "class") node.className = v;
    else if (k === "dataset") Object.assign(node.dataset, v);
    else if (v === true) node.setAttribute(k, "");
    else node.setAttribute(k, String(v));
  }
  for (const c of children.flat()) {
    if (c === undefined || c === null || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

export function fmt(x, digits = 3) {
  if (x === null || x === undefined || Number.isNaN(x)) return "—";
  if (typeof x !== "number") return String(x);
  if (x !== 0 && (Math.abs(x) >= 1e5 || Math.abs(x) < 1e-3)) return x.toExponential(2);
  return x.toFixed(digits);
}

export function fmtPm(mean, sem, digits = 3) {
  if (mean === null || mean === undefined) return "—";
  return sem === null || sem === undefined ? fmt(mean, digits) : `${fmt(mean, digits)} ± ${fmt(sem, digits)}`;
}

export function fmtTime(iso) {
  if (!iso) return "—";
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return String(iso);
  return d.toLocaleString([], { year: "numeric", month: "2-digit", day: "2-digit", hour: "2-digit", minute: "2-digit", second: "2-digit" });
}

export function fmtDuration(s) {
  if (s === null || s === undefined) return "—";
  if (s < 60) return `${s.toFixed(1)} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
  return `${Math.floor(s / 3600)} h ${Math.round((s % 3600) / 60)} min`;
}

export function badge(status) {
  return el("span", { class: `badge ${status}` }, String(status || "").replace(/_/g, " "));
}

/** Show an error (ApiError or Error or string) in a target element, in words. */
export function showError(target, err) {
  const node = typeof target === "string" ? $(target) : target;
  const msg = err ? (err.message || String(err)) : "";
  if (node) node.textContent = msg;
  else if (msg) globalError(msg);
}

export function globalError(msg) {
  const b = $("#global-error");
  if (!b) return;
  b.textContent = msg || "";
  b.hidden = !msg;
}

export function clearFieldErrors(form) {
  form.querySelectorAll(".field-error").forEach((n) => n.remove());
  form.querySelectorAll(".invalid").forEach((n) => n.classList.remove("invalid"));
}

/** Put each 422 field message next to its field (labels carry data-field="<api name>"). */
export function showFieldErrors(form, fields) {
  const unplaced = [];
  for (const [name, msg] of Object.entries(fields || {})) {
    const label = form.querySelector(`[data-field="${CSS.escape(name)}"]`);
    if (!label) { unplaced.push(`${name}: ${msg}`); continue; }
    const input = label.tagName === "FIELDSET" ? null : label.querySelector("input, select, textarea");
    if (input) input.classList.add("invalid");
    const note = el("span", { class: "field-error", role: "alert" }, msg);
    if (label.tagName === "FIELDSET") label.querySelector("legend").after(note);
    else label.append(note);
  }
  return unplaced;
}

let me = null;
export function currentUser() { return me; }
export function canWrite() { return !!me && me.role === "operator"; }

/** Require a login; fill the header; hide write controls from anyone who is not an operator. */
export async function requireLogin() {
  const s = session();
  if (!s) {
    location.href = `/login?next=${encodeURIComponent(location.pathname)}`;
    return new Promise(() => {}); // the page is leaving
  }
  try {
    me = await api("GET", "/api/me");
  } catch (err) {
    if (err.status !== 401) globalError(`Could not check your login: ${err.message}`);
    me = s.user;
    if (!me) throw err;
  }
  const who = $("#who");
  if (who) {
    who.replaceChildren(
      el("span", {}, `${me.username} (${me.role})`),
      el("button", { id: "logout", onclick: async () => {
        clearSession();
        location.href = "/login";
      } }, "Log out"));
  }
  applyRole();
  return me;
}

export function applyRole(root = document) {
  const write = canWrite();
  root.querySelectorAll(".write-only").forEach((n) => n.classList.toggle("hidden-for-role", !write));
}

/** Fetch with the token and save the answer as a file (export buttons). */
export async function download(path, filename) {
  const response = await api("GET", path, { raw: true, headers: { Accept: "*/*" } });
  const blob = await response.blob();
  const url = URL.createObjectURL(blob);
  const a = el("a", { href: url, download: filename });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 5000);
}

export function plotlyAvailable() {
  return typeof window.Plotly !== "undefined";
}

export const PLOT_CONFIG = { displaylogo: false, responsive: true, modeBarButtonsToRemove: ["sendDataToCloud"] };
