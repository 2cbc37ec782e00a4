// The write controls for one trial: preview, confirm, run, measurements, fail/abandon/resolve.
import { api, newIdempotencyKey } from "./api.js";
import { canWrite, el, fmt } from "./ui.js";
import { openPreview, openReplay } from "./viz.js";

const PRE_RUN = new Set(["proposed", "awaiting_confirmation", "queued"]);
const MEASURABLE = new Set(["queued", "running", "completed", "needs_review"]);
const TERMINAL = new Set(["completed", "failed", "abandoned"]);
export const UNITS = ["m/s", "m", "N", "score"];

function box(title, ...children) {
  return el("div", { class: "action-box" }, el("h3", {}, title), ...children);
}

/** Mean and standard error of the mean (sample sd / √n) of finite numbers. */
export function meanSem(values) {
  const n = values.length;
  if (!n) return { mean: null, sem: null };
  const mean = values.reduce((a, b) => a + b, 0) / n;
  if (n < 2) return { mean, sem: null };
  const varS = values.reduce((a, b) => a + (b - mean) ** 2, 0) / (n - 1);
  return { mean, sem: Math.sqrt(varS / n) };
}

/** Parse a typed value: a finite number, or words saying why not. */
export function parseValue(raw) {
  const text = String(raw).trim();
  if (text === "") return { error: "is empty" };
  const normalised = text.replace(",", ".");
  if (!/^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/.test(normalised)) return { error: `“${text}” is not a number` };
  const v = Number(normalised);
  if (!Number.isFinite(v)) return { error: `“${text}” is not a finite number` };
  return { value: v };
}

function measurementBox(trial, defaultUnit, done) {
  const rows = el("div", { class: "repeats" });
  const summary = el("p", { class: "summary-line", id: "measure-summary" });
  const error = el("p", { class: "error", id: "measure-error", role: "alert" });
  let idempotencyKey = newIdempotencyKey();

  function addRow(unit = defaultUnit) {
    const i = rows.children.length + 1;
    const row = el("div", { class: "repeat-row" },
      el("span", { class: "muted" }, `#${i}`),
      el("input", { class: "m-value", "aria-label": `repeat ${i} value`, inputmode: "decimal", placeholder: "value" }),
      el("select", { class: "m-unit", "aria-label": `repeat ${i} unit` }, UNITS.map((u) => el("option", { value: u, selected: u === unit }, u))),
      el("input", { class: "m-note", "aria-label": `repeat ${i} note`, placeholder: "note (optional)" }),
      el("button", { type: "button", title: "remove this repeat", onclick: () => { row.remove(); refresh(); } }, "×"));
    rows.append(row);
    row.querySelector(".m-value").addEventListener("input", refresh);
    row.querySelector(".m-unit").addEventListener("change", refresh);
    refresh();
  }

  function read(strict = false) {
    const repeats = [];
    const problems = [];
    [...rows.children].forEach((row, i) => {
      const input = row.querySelector(".m-value");
      const parsed = parseValue(input.value);
      const unit = row.querySelector(".m-unit").value;
      const note = row.querySelector(".m-note").value;
      // While typing, only a non-empty wrong value is marked; on save, empty ones too.
      input.classList.toggle("invalid", !!parsed.error && (strict || input.value.trim() !== ""));
      if (parsed.error) problems.push(`repeat ${i + 1}: ${parsed.error}`);
      else repeats.push({ value: parsed.value, unit, note });
    });
    const units = new Set(repeats.map((r) => r.unit));
    if (units.size > 1) problems.push(`all repeats need the same unit (got ${[...units].join(", ")})`);
    if (!rows.children.length) problems.push("add at least one repeat");
    return { repeats, problems };
  }

  function refresh() {
    const { repeats } = read();
    const { mean, sem } = meanSem(repeats.map((r) => r.value));
    const unit = repeats.length ? repeats[0].unit : "";
    summary.textContent = repeats.length
      ? `mean ${fmt(mean)}${sem !== null ? ` ± ${fmt(sem)} (SEM)` : ""} ${unit} over ${repeats.length} repeat${repeats.length > 1 ? "s" : ""}`
      : "no valid repeat yet";
  }

  const save = el("button", { class: "primary", type: "submit", id: "measure-save" }, "Save measurement");
  const form = el("form", { id: "measure-form", dataset: { trialId: trial.id }, novalidate: true, onsubmit: async (ev) => {
    ev.preventDefault();
    error.textContent = "";
    const { repeats, problems } = read(true);
    if (problems.length) { error.textContent = `Not saved: ${problems.join("; ")}.`; return; }
    save.disabled = true;
    try {
      await api("POST", `/api/trials/${trial.id}/measurements`, { body: { repeats }, headers: { "Idempotency-Key": idempotencyKey } });
      idempotencyKey = newIdempotencyKey();
      rows.replaceChildren();
      addRow();
      done(`Saved ${repeats.length} repeat${repeats.length > 1 ? "s" : ""} for trial ${trial.index ?? trial.id}.`);
    } catch (err) {
      // A refused post stored nothing, so a new key is right for the corrected values.
      if (err.status >= 400 && err.status < 500) idempotencyKey = newIdempotencyKey();
      error.textContent = `Not saved: ${err.message}`;
    } finally {
      save.disabled = false;
    }
  } },
  rows,
  el("div", { class: "row gap" }, el("button", { type: "button", id: "measure-add", onclick: () => addRow(rows.lastElementChild?.querySelector(".m-unit").value || defaultUnit) }, "+ repeat"), save),
  summary, error);
  addRow();
  return box(`Enter measurement${trial.n_measurements ? ` (has ${trial.n_measurements})` : ""}`, form);
}

function reasonBox(trial, hardware, done) {
  const error = el("p", { class: "error", role: "alert", id: "reason-error" });
  const reason = el("input", { id: "reason-input", placeholder: "reason (required), e.g. tracker lost the tip" });
  async function act(path, body, what) {
    error.textContent = "";
    if (!reason.value.trim()) { error.textContent = `Give a reason to ${what}.`; reason.classList.add("invalid"); return; }
    reason.classList.remove("invalid");
    try {
      await api("POST", `/api/trials/${trial.id}/${path}`, { body: { ...body, reason: reason.value.trim() } });
      done(`Trial ${trial.index ?? trial.id}: ${what} done.`);
    } catch (err) {
      error.textContent = `Refused: ${err.message}`;
    }
  }
  const buttons = [];
  if (trial.status === "needs_review") {
    const decision = el("select", { id: "resolve-decision" },
      el("option", { value: "requeue" }, hardware ? "requeue (run it again after a new confirmation)" : "requeue (run it again)"),
      el("option", { value: "fail" }, "fail"),
      el("option", { value: "complete" }, "complete (keep its measurements)"),
      el("option", { value: "abandon" }, "abandon"));
    buttons.push(decision, el("button", { id: "resolve-button", onclick: () => act("resolve", { decision: decision.value }, `resolve (${decision.value})`) }, "Resolve review"));
  }
  buttons.push(
    el("button", { class: "danger", id: "fail-button", onclick: () => act("fail", {}, "mark failed") }, "Mark failed"),
    el("button", { class: "danger", id: "abandon-button", onclick: () => act("abandon", {}, "abandon") }, "Abandon"));
  return box(trial.status === "needs_review" ? "Needs review: decide" : "Fail or abandon", el("label", {}, "Reason", reason), el("div", { class: "row gap" }, ...buttons), error);
}

/**
 * Render the controls that fit this trial's status into `container`.
 * ctx: {experiment, incumbentId, onChange(message)}
 */
export function renderTrialActions(container, trial, ctx) {
  // A live update (e.g. the worker finishing this trial) must not wipe repeats the operator
  // is typing: keep the measurement form of the same trial when it holds any input.
  const typing = container.querySelector("#measure-form");
  const keepForm = typing && typing.dataset.trialId === String(trial.id)
    && [...typing.querySelectorAll("input")].some((i) => i.value.trim() !== "");
  try {
    buildTrialActions(container, trial, ctx);
  } finally {
    const fresh = keepForm && container.querySelector("#measure-form");
    if (fresh) fresh.replaceWith(typing);
  }
}

function buildTrialActions(container, trial, ctx) {
  container.replaceChildren();
  const { experiment } = ctx;
  const done = (msg) => ctx.onChange(msg);
  const hardware = experiment.target === "hardware";
  const status = trial.status;
  const viewBox = el("div", { class: "row gap" });
  if (!TERMINAL.has(status) && canWrite()) {
    viewBox.append(el("button", { id: "preview-button", class: "primary", onclick: () => openPreview(trial, ctx.incumbentId) }, "Preview (3D)"));
  } else {
    viewBox.append(el("button", { id: "replay-trial-button", onclick: () => openReplay(trial, ctx.incumbentId) }, "3D replay"));
  }
  container.append(viewBox);
  if (!canWrite()) return;

  if (hardware && (status === "proposed" || status === "awaiting_confirmation")) {
    const error = el("p", { class: "error", role: "alert", id: "confirm-error" });
    const check = el("input", { type: "checkbox", id: "confirm-check" });
    const button = el("button", { class: "safety", id: "confirm-button", onclick: async () => {
      error.textContent = "";
      if (!check.checked) { error.textContent = "Tick the box first: you have looked at this schedule and its preview, and the robot's area is clear."; return; }
      button.disabled = true;
      try {
        await api("POST", `/api/trials/${trial.id}/confirm`, { body: { schedule_hash: trial.schedule_hash } });
        done(`Trial ${trial.index ?? trial.id} confirmed and queued for the robot.`);
      } catch (err) {
        error.textContent = `Not confirmed: ${err.message}`;
        button.disabled = false;
      }
    } }, "Confirm safety & queue");
    container.append(box("Safety gate",
      el("p", { class: "small muted" }, `You confirm exactly this schedule (hash ${String(trial.schedule_hash || "?").slice(0, 12)}…); any change needs a new confirmation.`),
      el("label", { class: "inline" }, check, "I have checked this schedule and its 3D preview; the robot's area is clear."),
      el("div", {}, button), error));
  }
  if (!hardware && PRE_RUN.has(status)) {
    const error = el("p", { class: "error", role: "alert" });
    container.append(box("Simulator",
      el("button", { id: "run-button", onclick: async (ev) => {
        ev.target.disabled = true;
        error.textContent = "";
        try {
          await api("POST", `/api/trials/${trial.id}/run`);
          done(`Trial ${trial.index ?? trial.id} ran in the simulator.`);
        } catch (err) { error.textContent = `Not run: ${err.message}`; ev.target.disabled = false; }
      } }, "Run in the simulator now"),
      el("span", { class: "muted small" }, " (or let a sim worker claim it)"), error));
  }
  if (MEASURABLE.has(status)) {
    container.append(measurementBox(trial, experiment.objective_unit || "score", done));
  }
  if (!TERMINAL.has(status)) container.append(reasonBox(trial, hardware, done));
}
