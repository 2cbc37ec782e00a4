import { api } from "./api.js";
import { SIM_MAX_PRESSURE_PA } from "/api-schema.js";
import { renderTrialActions } from "./actions.js";
import { bestSoFar, driftChart, relevance, scheduleHeatmap, slices } from "./plots.js";
import { closeUnlessFor } from "./viz.js";
import { renderSimPrior } from "./twins.js";
import { $, applyRole, badge, canWrite, download, el, fmt, fmtDuration, fmtPm, fmtTime, requireLogin, showError } from "./ui.js";

const experimentId = window.HANDFUL.experimentId;
const ACTIVE_ORDER = ["needs_review", "running", "queued", "awaiting_confirmation", "proposed"];
let experiment = null;
let trials = [];
let version = null;
let nextKey = null;
let selectedId = null; // a trial the operator picked (e.g. from the awaiting-measurement list)

/** How the experiment applies each schedule row (a ramped schedule is a different motion). */
function holdText(e) {
  return (e && e.command_hold) === "linear" ? "commands ramped over each step (linear hold)" : "commands held each step (zero hold)";
}

function say(message) {
  $("#exp-ok").textContent = message || "";
  if (message) setTimeout(() => { if ($("#exp-ok").textContent === message) $("#exp-ok").textContent = ""; }, 8000);
}

/** LimitsRead: nominal_pa (12 values), max_step_pa, source_pa; null limits: the sim range. */
function limitsText(e) {
  if (!e.limits) return `sim range 0–${fmt(SIM_MAX_PRESSURE_PA / 1000, 1)} kPa`;
  const { nominal_pa: nominal, max_step_pa: step, source_pa: source } = e.limits;
  const nom = new Set(nominal).size === 1 ? `${fmt(nominal[0] / 1000, 1)}` : nominal.map((v) => fmt(v / 1000, 0)).join("/");
  return `nominal ${nom} kPa ± ${fmt(step / 1000, 1)} kPa, source ${fmt(source / 1000, 1)} kPa`;
}

function boundsPa(e) {
  if (!e.limits) return { lowerPa: 0, upperPa: SIM_MAX_PRESSURE_PA };
  const { nominal_pa: nominal, max_step_pa: step } = e.limits;
  return { lowerPa: Math.min(...nominal) - step, upperPa: Math.max(...nominal) + step };
}

function incumbent() {
  const done = trials.filter((t) => t.status === "completed" && t.objective !== null);
  return done.length ? done.reduce((a, b) => (b.objective > a.objective ? b : a)) : null;
}

/** Trials that ran and await a measurement from the objective's sources. */
function awaitingMeasurement() {
  return trials.filter((t) => t.status === "completed" && (t.objective === null || t.objective === undefined) && experiment.target === "hardware");
}

function pickNext() {
  const picked = selectedId !== null && trials.find((x) => x.id === selectedId);
  if (picked) return picked;
  for (const status of ACTIVE_ORDER) {
    const t = trials.find((x) => x.status === status);
    if (t) return t;
  }
  const sorted = trials.slice().sort((a, b) => b.index - a.index);
  return sorted[0] || null;
}

function renderHeader() {
  const e = experiment;
  $("#exp-title").textContent = `${e.name || "Experiment"} (#${e.id})`;
  document.title = `${e.name || "Experiment"} · handful`;
  $("#exp-status").replaceChildren(badge(e.status));
  $("#exp-status").className = `badge ${e.status}`;
  const done = trials.filter((t) => t.status === "completed").length;
  const best = incumbent();
  const used = e.n_budget_used ?? trials.filter((t) => t.status !== "abandoned").length;
  $("#exp-summary").textContent = [
    `${e.task} on ${e.target}`,
    `P = ${e.levels}, H = ${e.horizon}${e.with_release ? " + release step" : ""}`,
    holdText(e),
    `${e.method}${e.acquisition ? ` (${e.acquisition}${e.kappa !== null && e.kappa !== undefined ? `, κ = ${e.kappa}` : ""})` : ""}, ${e.n_initial} initial, seed ${e.seed}`,
    `objective in ${e.objective_unit} from ${(e.objective_sources || []).join(" + ")}`,
    limitsText(e),
    `${done} / ${e.budget ?? "∞"} trials done`,
    e.budget_reached ? `budget of ${e.budget} trials reached (${used} used): raise it to go on` : "",
    `best so far ${best ? fmtPm(best.objective, best.objective_sem) : "—"}`,
    `by ${e.created_by || "?"}, ${fmtTime(e.created_at)}`,
  ].filter(Boolean).join(" · ");
  $("#suggest-button").disabled = !!e.budget_reached;
  $("#suggest-button").title = e.budget_reached ? `The budget of ${e.budget} trials is reached; raise it below to suggest more.` : "";
  renderAwaiting();
  if (document.activeElement !== $("#exp-status-select")) $("#exp-status-select").value = e.status;
  if (document.activeElement !== $("#exp-budget-input")) $("#exp-budget-input").value = e.budget ?? "";
  if (document.activeElement !== $("#exp-notes")) $("#exp-notes").value = e.notes ?? "";
}

function renderAwaiting() {
  const waiting = awaitingMeasurement();
  $("#awaiting-card").hidden = !waiting.length;
  $("#awaiting-list").replaceChildren(...waiting.map((t) => el("button", {
    class: selectedId === t.id ? "primary" : "", dataset: { trialId: t.id }, onclick: () => { selectedId = t.id; nextKey = null; renderNext(); renderAwaiting(); $("#next-card").scrollIntoView({ block: "start" }); },
  }, `Measure trial ${t.index}`)));
}

function renderTable() {
  const tbody = $("#trials-table tbody");
  const rows = trials.slice().sort((a, b) => b.index - a.index).map((t) => el("tr", {
    class: "clickable", dataset: { trialId: t.id, status: t.status }, onclick: () => { location.href = `/trials/${t.id}`; } },
  el("td", {}, el("a", { href: `/trials/${t.id}` }, t.index), t.source === "reference" ? el("span", { class: "small muted", title: "a drift check: the reference θ again" }, " ref") : null),
  el("td", {}, badge(t.status), t.status_reason ? el("div", { class: "small muted" }, t.status_reason) : null),
  el("td", { class: "theta", title: (t.executed_theta || t.theta || []).join(", ") }, (t.executed_theta || t.theta || []).map((v) => v.toFixed(3)).join(", ")),
  el("td", { class: "objective" }, fmtPm(t.objective, t.objective_sem)),
  el("td", {}, t.n_measurements ?? 0),
  el("td", {}, t.predicted_mean !== null && t.predicted_mean !== undefined ? fmtPm(t.predicted_mean, t.predicted_std) : "—"),
  el("td", {}, t.confirmed_by ? `${t.created_by}; confirmed by ${t.confirmed_by}` : t.created_by || "—"),
  el("td", {}, fmtTime(t.finished_at || t.started_at || t.created_at)),
  el("td", {}, fmtDuration(t.duration_s))));
  tbody.replaceChildren(...rows);
  if (!rows.length) tbody.append(el("tr", {}, el("td", { colspan: 9, class: "muted" }, "No trials yet.")));
}

function renderNext() {
  const t = pickNext();
  closeUnlessFor(t ? t.id : null);
  const key = t ? `${t.id}:${t.status}:${t.n_measurements}:${t.updated_at}:${t.schedule_hash}` : "none";
  if (key === nextKey) return;
  nextKey = key;
  $("#next-empty").hidden = !!t;
  $("#next-body").hidden = !t;
  if (!t) { $("#next-title").textContent = ""; return; }
  const active = ACTIVE_ORDER.includes(t.status);
  $("#next-title").textContent = `${active ? "" : "(latest) "}trial ${t.index}`;
  $("#next-meta").replaceChildren(badge(t.status), ` θ = [${(t.theta || []).map((v) => v.toFixed(3)).join(", ")}]`,
    t.release_step ? ` · release after step ${t.release_step}` : "",
    t.confirmed_by ? ` · confirmed by ${t.confirmed_by} ${fmtTime(t.confirmed_at)}` : "",
    t.source === "reference" ? " · reference trial (drift check: the reference θ again)" : "");
  $("#next-prediction").replaceChildren(
    t.predicted_mean !== null && t.predicted_mean !== undefined
      ? `GP predicts ${fmtPm(t.predicted_mean, t.predicted_std)} (mean ± std)`
      : "No GP prediction for this trial (random initial trial, or not a BO experiment).",
    el("div", { id: "next-preview-summary", class: "small" }));
  scheduleHeatmap($("#heatmap"), t.pressure_schedule_pa, { title: `pressure schedule (kPa): 12 chambers × H steps, ${holdText(experiment)}`, releaseStep: t.release_step, ...boundsPa(experiment) });
  const best = incumbent();
  renderTrialActions($("#trial-actions"), t, {
    experiment, incumbentId: best && best.id !== t.id ? best.id : null, onChange: (msg) => { say(msg); if (selectedId === t.id) selectedId = null; refresh(true); },
  });
}

async function renderModel() {
  const empty = $("#model-empty");
  try {
    const model = await api("GET", `/api/experiments/${experimentId}/model`);
    if (!model || !model.lengthscales) {
      empty.textContent = model && model.message ? model.message : "No GP model yet (it needs completed trials and a BO experiment).";
      $("#model-plots").hidden = true;
      return;
    }
    $("#model-plots").hidden = false;
    empty.textContent = [model.message || `GP fitted on ${model.n_observations} observations; best trial ${model.incumbent_trial_index ?? "?"} (${fmt(model.incumbent_objective)}).`,
      model.n_refused ? `${model.n_refused} abandoned trial${model.n_refused > 1 ? "s" : ""} count as objective ${fmt(model.refused_penalty)} (below the worst), so the model avoids that region; their schedules are never suggested again.` : ""].filter(Boolean).join(" ");
    relevance($("#relevance-plot"), model.lengthscales);
    slices($("#slices-plot"), model.slices || [], model.incumbent_theta, model.lengthscales);
  } catch (err) {
    $("#model-plots").hidden = true;
    empty.textContent = `No model insight: ${err.message}`;
  }
}

/** The drift check: the reference's scores and band (DriftRead), the warning, the schedule. */
async function renderDrift() {
  const card = $("#drift-card");
  card.hidden = experiment.target !== "hardware";
  if (card.hidden) return;
  try {
    const drift = await api("GET", `/api/experiments/${experimentId}/drift`);
    const ref = drift.reference;
    $("#drift-warning").textContent = drift.shifted ? drift.warning : "";
    $("#drift-warning").hidden = !drift.shifted;
    const plotted = (drift.points || []).length + (drift.earlier || []).length;
    $("#drift-plot").hidden = !plotted;
    if (plotted) driftChart($("#drift-plot"), drift);
    $("#drift-status").textContent = [
      ref ? `Reference: the θ of ${drift.reference_trial_index ? `trial ${drift.reference_trial_index}` : "the incumbent (frozen when the first reference is made)"}${ref.theta_from === "incumbent" && drift.reference_trial_index ? " (the incumbent, frozen)" : ""}, every ${ref.every} hardware trials.` : "",
      drift.next_reference_in !== null && drift.next_reference_in !== undefined ? (drift.next_reference_in ? `Next reference after ${drift.next_reference_in} more trial${drift.next_reference_in > 1 ? "s" : ""}.` : "The next suggestion brings a reference trial first.") : "",
      `${(drift.points || []).length} reference${(drift.points || []).length === 1 ? "" : "s"} scored.`,
      drift.message || "",
    ].filter(Boolean).join(" ");
    $("#drift-unit").textContent = experiment.objective_unit;
    const form = $("#drift-form");
    if (ref && !form.contains(document.activeElement)) {
      $("#drift-every").value = ref.every;
      $("#drift-from").value = ref.theta_from;
      $("#drift-trial").value = ref.theta_from === "trial" ? (drift.reference_trial_index ?? "") : "";
      $("#drift-m").value = ref.baseline_n;
      $("#drift-tolerance").value = ref.tolerance ?? "";
      $("#drift-trial-label").hidden = ref.theta_from !== "trial";
    }
    $("#drift-stop").hidden = !ref;
  } catch (err) {
    $("#drift-status").textContent = `Drift check not shown: ${err.message}`;
  }
}

function wireDrift() {
  $("#drift-from").onchange = () => { $("#drift-trial-label").hidden = $("#drift-from").value !== "trial"; };
  $("#drift-form").onsubmit = async (ev) => {
    ev.preventDefault();
    const whole = (text) => (/^\d+$/.test(text.trim()) ? Number(text) : NaN);
    const body = { every: whole($("#drift-every").value), theta_from: $("#drift-from").value, baseline_n: whole($("#drift-m").value) };
    if (!Number.isInteger(body.every) || body.every < 2) { showError("#exp-error", `Not scheduled: “${$("#drift-every").value}” is not a whole number of trials of 2 or more (every k-th hardware trial is a reference).`); return; }
    if (!Number.isInteger(body.baseline_n) || body.baseline_n < 2) { showError("#exp-error", `Not scheduled: the band needs at least 2 references, not “${$("#drift-m").value}”.`); return; }
    if (body.theta_from === "trial") body.trial_index = whole($("#drift-trial").value);
    if (body.theta_from === "trial" && !Number.isInteger(body.trial_index)) { showError("#exp-error", "Not scheduled: give the number of the trial whose θ to repeat."); return; }
    const tol = $("#drift-tolerance").value.trim();
    if (tol) {
      body.tolerance = Number(tol);
      if (!Number.isFinite(body.tolerance) || body.tolerance <= 0) { showError("#exp-error", `Not scheduled: the band's half-width “${tol}” is not a positive number of ${experiment.objective_unit}.`); return; }
    }
    try {
      await api("PUT", `/api/experiments/${experimentId}/reference`, { body });
      showError("#exp-error", null);
      say(`Drift check scheduled: a reference every ${body.every} hardware trials.`);
      await refresh(true);
    } catch (err) { showError("#exp-error", err); }
  };
  $("#drift-stop").onclick = async () => {
    try {
      await api("DELETE", `/api/experiments/${experimentId}/reference`);
      say("Drift check stopped.");
      await refresh(true);
    } catch (err) { showError("#exp-error", err); }
  };
}

async function renderAudit() {
  if (!$("#audit-box").open) return;
  try {
    const rows = await api("GET", `/api/experiments/${experimentId}/audit?limit=300`);
    $("#exp-audit-table tbody").replaceChildren(...rows.map((a) => el("tr", {},
      el("td", {}, fmtTime(a.at)), el("td", {}, a.actor), el("td", {}, a.action),
      el("td", {}, a.trial_id ? el("a", { href: `/trials/${a.trial_id}` }, `trial ${trials.find((t) => t.id === a.trial_id)?.index ?? "?"}`) : "—"),
      el("td", {}, a.before || a.after ? `${a.before ?? "—"} → ${a.after ?? "—"}` : ""),
      el("td", {}, a.detail ? JSON.stringify(a.detail) : ""))));
  } catch (err) {
    $("#exp-audit-table tbody").replaceChildren(el("tr", {}, el("td", { colspan: 6, class: "error" }, `Audit log not shown: ${err.message}`)));
  }
}

async function refresh(force = false) {
  try {
    const [e, t] = await Promise.all([
      api("GET", `/api/experiments/${experimentId}`),
      api("GET", `/api/experiments/${experimentId}/trials`),
    ]);
    experiment = e;
    trials = t;
    version = e.version;
    renderHeader();
    renderTable();
    bestSoFar($("#best-plot"), trials);
    if (force) nextKey = null;
    renderNext();
    applyRole();
    renderModel();
    renderDrift();
    renderAudit();
    renderSimPrior(experiment, (msg) => { say(msg); refresh(true); });
    showError("#exp-error", null);
  } catch (err) {
    showError("#exp-error", err);
  }
}

async function currentVersion() {
  return (await api("GET", `/api/experiments/${experimentId}/version`)).version;
}

async function poll() {
  try {
    const v = await currentVersion();
    $("#live-indicator").textContent = "live";
    if (v !== version) { version = v; await refresh(); }
  } catch (err) {
    $("#live-indicator").textContent = `updates paused: ${err.message}`;
  }
  setTimeout(poll, 2000);
}

function wireActions() {
  $("#audit-box").addEventListener("toggle", renderAudit);
  $("#export-csv").onclick = () => download(`/api/experiments/${experimentId}/export?format=csv`, `experiment-${experimentId}.csv`).catch((err) => showError("#exp-error", err));
  $("#export-json").onclick = () => download(`/api/experiments/${experimentId}/export?format=json`, `experiment-${experimentId}.json`).catch((err) => showError("#exp-error", err));
  if (!canWrite()) return;
  wireDrift();
  $("#suggest-button").onclick = async (ev) => {
    ev.target.disabled = true;
    showError("#exp-error", null);
    try {
      const n = Number($("#suggest-n").value);
      if (!Number.isInteger(n) || n < 1 || n > 100) { showError("#exp-error", "n must be a whole number from 1 to 100."); return; }
      const made = await api("POST", `/api/experiments/${experimentId}/suggest`, { body: { n } });
      say(made.length ? `Suggested trial ${made.map((t) => t.index).join(", ")}.` : "No new trial suggested.");
      selectedId = null;
      await refresh(true);
    } catch (err) { showError("#exp-error", err); } finally { ev.target.disabled = false; }
  };
  $("#attach-toggle").onclick = () => { $("#attach-form").hidden = !$("#attach-form").hidden; };
  $("#import-toggle").onclick = () => { $("#import-form").hidden = !$("#import-form").hidden; };
  $("#attach-form").onsubmit = async (ev) => {
    ev.preventDefault();
    const parts = $("#attach-theta").value.split(/[,\s]+/).filter(Boolean);
    const theta = parts.map(Number);
    if (!parts.length || theta.some((v) => !Number.isFinite(v))) { showError("#exp-error", "θ must be numbers separated by commas."); return; }
    try {
      const t = await api("POST", `/api/experiments/${experimentId}/trials`, { body: { theta, note: $("#attach-note").value } });
      say(`Attached trial ${t.index}.`);
      $("#attach-form").hidden = true;
      await refresh(true);
    } catch (err) { showError("#exp-error", err); }
  };
  $("#import-form").onsubmit = async (ev) => {
    ev.preventDefault();
    let body;
    try { body = JSON.parse($("#import-json").value); } catch (err) { showError("#exp-error", `Not valid JSON: ${err.message}`); return; }
    try {
      const answer = await api("POST", `/api/experiments/${experimentId}/import`, { body });
      say(`Imported ${answer.length} observations.`);
      $("#import-form").hidden = true;
      await refresh(true);
    } catch (err) { showError("#exp-error", err); }
  };
  $("#notes-save").onclick = async () => {
    try {
      await api("PATCH", `/api/experiments/${experimentId}`, { body: { notes: $("#exp-notes").value } });
      say("Notes saved.");
      await refresh();
    } catch (err) { showError("#exp-error", err); }
  };
  $("#exp-save").onclick = async () => {
    const body = { status: $("#exp-status-select").value };
    const b = $("#exp-budget-input").value.trim();
    if (b) {
      const used = experiment.n_budget_used ?? 0;
      if (!/^\d+$/.test(b) || Number(b) < 1) { showError("#exp-error", `Not saved: budget “${b}” is not a whole number of trials (1 or more).`); return; }
      if (Number(b) < used) { showError("#exp-error", `Not saved: a budget of ${b} trials is below the ${used} trials this experiment already has.`); return; }
      body.budget = Number(b);
    }
    try {
      await api("PATCH", `/api/experiments/${experimentId}`, { body });
      say("Experiment saved.");
      await refresh();
    } catch (err) { showError("#exp-error", err); }
  };
}

requireLogin().then(async () => {
  wireActions();
  await refresh(true);
  setTimeout(poll, 2000);
});
