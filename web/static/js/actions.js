// The write controls for one trial: preview, confirm, run, measurements, fail/abandon/resolve.
import { api, newIdempotencyKey } from "./api.js";
import { canWrite, el, fmt, fmtDuration, fmtTime } from "./ui.js";
import { openPreview, openReplay } from "./viz.js";
import { gatePredictions } from "./twins.js";

const PRE_RUN = new Set(["proposed", "awaiting_confirmation", "queued"]);
const MEASURABLE = new Set(["queued", "running", "completed", "needs_review"]);
const TERMINAL = new Set(["completed", "failed", "abandoned"]);
export const UNITS = ["m/s", "m", "N", "score"];
export const TYPED_SOURCES = ["tape", "tracker"];

// Every "running for …" clock on the page ticks once a second.
setInterval(() => {
  for (const node of document.querySelectorAll("[data-started-at]")) {
    const s = (Date.now() - Date.parse(node.dataset.startedAt)) / 1000;
    node.textContent = fmtDuration(Math.max(0, s));
  }
}, 1000);

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
  if (/^[+-]?\d*,\d*$/.test(text) && /\d/.test(text)) {
    return { error: `“${text}” has a comma: type the decimals after a point (${text.replace(",", ".")})` };
  }
  if (!/^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/.test(text)) return { error: `“${text}” is not a number` };
  const v = Number(text);
  if (!Number.isFinite(v)) return { error: `“${text}” is not a finite number` };
  return { value: v };
}

/** The source an operator's repeat defaults to: the experiment's first typed objective source. */
export function defaultSource(experiment) {
  const first = (experiment.objective_sources || [])[0];
  return TYPED_SOURCES.includes(first) ? first : "tape";
}

function measurementBox(trial, defaultUnit, done, source = "tape") {
  const rows = el("div", { class: "repeats" });
  const summary = el("p", { class: "summary-line", id: "measure-summary" });
  const error = el("p", { class: "error", id: "measure-error", role: "alert" });
  let idempotencyKey = newIdempotencyKey();
  let saved = null;

  function addRow(unit = defaultUnit) {
    const i = rows.children.length + 1;
    const row = el("div", { class: "repeat-row" },
      el("span", { class: "muted" }, `#${i}`),
      el("input", { class: "m-value", "aria-label": `repeat ${i} value`, inputmode: "decimal", placeholder: "value" }),
      el("select", { class: "m-unit", "aria-label": `repeat ${i} unit` }, UNITS.map((u) => el("option", { value: u, selected: u === unit }, u))),
      el("select", { class: "m-source", "aria-label": `repeat ${i} source`, title: "what measured it" }, TYPED_SOURCES.map((x) => el("option", { value: x, selected: x === source }, x))),
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
      const from = row.querySelector(".m-source").value;
      // While typing, only a non-empty wrong value is marked; on save, empty ones too.
      input.classList.toggle("invalid", !!parsed.error && (strict || input.value.trim() !== ""));
      if (parsed.error) problems.push(`repeat ${i + 1}: ${parsed.error}`);
      else repeats.push({ value: parsed.value, unit, note, source: from });
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
      saved = await api("POST", `/api/trials/${trial.id}/measurements`, { body: { repeats }, headers: { "Idempotency-Key": idempotencyKey } });
      idempotencyKey = newIdempotencyKey();
      rows.replaceChildren();
      addRow();
      const receipt = saved;
      done(`Saved ${repeats.length} repeat${repeats.length > 1 ? "s" : ""} for trial ${trial.index}: objective now ${fmt(receipt?.objective)}${receipt?.objective_sem !== null && receipt?.objective_sem !== undefined ? ` ± ${fmt(receipt.objective_sem)}` : ""} over ${receipt?.n_measurements ?? "?"} counted repeat(s).`);
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
  return box(`Enter measurement for trial ${trial.index}${trial.n_measurements ? ` (has ${trial.n_measurements})` : ""}`, form);
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
      done(`Trial ${trial.index}: ${what} done.`);
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

/** A running hardware trial: how long it has run, and a Stop that aborts it through the worker. */
function stopBox(trial, done) {
  const error = el("p", { class: "error", role: "alert", id: "stop-error" });
  const reason = el("input", { id: "stop-reason", value: "stopped by the operator", "aria-label": "why stop" });
  const button = el("button", { class: "danger", id: "stop-button", onclick: async () => {
    error.textContent = "";
    if (!reason.value.trim()) { error.textContent = "Give a reason to stop."; return; }
    button.disabled = true;
    try {
      await api("POST", `/api/trials/${trial.id}/fail`, { body: { reason: reason.value.trim() } });
      done(`Trial ${trial.index} stopped: the worker aborts it and the robot vents to nominal.`);
    } catch (err) { error.textContent = `Not stopped: ${err.message}`; button.disabled = false; }
  } }, "Stop");
  const clock = el("strong", { id: "elapsed", dataset: { startedAt: trial.started_at || trial.updated_at } }, "…");
  return box(`Running on the robot: trial ${trial.index}`,
    el("p", {}, "Running for ", clock, " (a schedule lasts about 5 s)."),
    el("label", {}, "Reason", reason), el("div", {}, button), error);
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
        done(`Trial ${trial.index} confirmed and queued for the robot.`);
      } catch (err) {
        error.textContent = `Not confirmed: ${err.message}`;
        button.disabled = false;
      }
    } }, "Confirm safety & queue");
    const mine = (trial.previews || []).filter((p) => p.schedule_hash === trial.schedule_hash);
    container.append(box(`Safety gate: trial ${trial.index}`,
      gatePredictions(trial, experiment),
      el("p", { class: "small muted" }, `You confirm exactly this schedule (hash ${String(trial.schedule_hash || "?").slice(0, 12)}…); any change needs a new confirmation.`),
      el("p", { class: "small", id: "preview-state" }, mine.length
        ? `Previewed by ${mine.map((p) => `${p.previewed_by} (${fmtTime(p.previewed_at)})`).join(", ")}.`
        : "The server accepts a confirmation only after your own 3D preview of this exact schedule has run: press “Preview (3D)” first."),
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
          done(`Trial ${trial.index} ran in the simulator.`);
        } catch (err) { error.textContent = `Not run: ${err.message}`; ev.target.disabled = false; }
      } }, "Run in the simulator now"),
      el("span", { class: "muted small" }, " (or let a sim worker claim it)"), error));
  }
  if (hardware && status === "running") container.append(stopBox(trial, done));
  // Sim trials are scored by the simulator: no operator form (the API still takes a value).
  if (hardware && MEASURABLE.has(status)) {
    container.append(measurementBox(trial, experiment.objective_unit || "score", done, defaultSource(experiment)));
  }
  if (!TERMINAL.has(status) && !(hardware && status === "running")) container.append(reasonBox(trial, hardware, done));
}
