import { api } from "./api.js";
import { meanSem, parseValue, renderTrialActions } from "./actions.js";
import { line, scheduleHeatmap } from "./plots.js";
import { $, applyRole, canWrite, download, el, fmt, fmtDuration, fmtPm, fmtTime, requireLogin, showError } from "./ui.js";
import { openReplay } from "./viz.js";
import { basisText, twinText } from "./twins.js";

const trialId = window.HANDFUL.trialId;
let lastKey = null;

function fact(term, value) {
  return [el("dt", {}, term), el("dd", {}, value ?? "—")];
}

function renderFacts(t, e) {
  $("#trial-title").textContent = `Trial ${t.index} of `;
  $("#trial-title").append(el("a", { href: `/experiments/${e.id}` }, e.name || `experiment ${e.id}`));
  document.title = `Trial ${t.index} · handful`;
  $("#trial-status").replaceChildren(t.status.replace(/_/g, " "));
  $("#trial-status").className = `badge ${t.status}`;
  const hold = e.command_hold === "linear" ? "commands ramped over each step (linear hold)" : "commands held each step (zero hold)";
  $("#trial-summary").textContent = `${e.task} on ${e.target}, ${hold}; source: ${t.source || "?"}${t.note ? `; note: ${t.note}` : ""}`;
  $("#trial-facts").replaceChildren(
    ...fact("Objective ± SEM", fmtPm(t.objective, t.objective_sem)),
    ...fact("Measurements", String(t.n_measurements ?? 0)),
    ...fact("GP prediction", t.predicted_mean !== null && t.predicted_mean !== undefined ? fmtPm(t.predicted_mean, t.predicted_std) : "—"),
    ...(e.target === "hardware" ? twinFacts(t, e) : []),
    ...fact("Suggestion leaned on", basisText(t.suggestion_basis)),
    ...fact("Status reason", t.status_reason || "—"),
    ...fact("θ planned", `[${(t.theta || []).map((v) => v.toFixed(4)).join(", ")}]`),
    ...fact("θ executed", t.executed_theta ? `[${t.executed_theta.map((v) => v.toFixed(4)).join(", ")}]` : "—"),
    ...fact("Release step (planned / executed)", `${t.release_step ?? "—"} / ${t.executed_release_step ?? "—"}`),
    ...fact("Schedule hash", t.schedule_hash ? `${t.schedule_hash.slice(0, 16)}…` : "—"),
    ...fact("Confirmed", t.confirmed_by ? `by ${t.confirmed_by}, ${fmtTime(t.confirmed_at)}` : "—"),
    ...fact("Attempts", String(t.attempts ?? 0)),
    ...fact("Created", `${t.created_by || "?"}, ${fmtTime(t.created_at)}`),
    ...fact("Ran", `${fmtTime(t.started_at)} → ${fmtTime(t.finished_at)} (${fmtDuration(t.duration_s)})`));
}

/** The sim twins of a hardware trial: of its plan, and of what the robot executed. */
function twinFacts(t, e) {
  const byKind = Object.fromEntries((t.twins || []).map((x) => [x.kind, x]));
  const out = fact("Sim twin of the plan", twinText(byKind.planned, e.objective_unit));
  if (t.executed_pressure_schedule_pa) {
    const ran = byKind.executed;
    const gap = ran && ran.predicted_objective !== null && t.objective !== null ? `; hardware − twin ${fmt(t.objective - ran.predicted_objective)}` : "";
    out.push(...fact("Sim twin of what ran", `${twinText(ran, e.objective_unit)}${gap}`));
  }
  return out;
}

function renderSchedules(t) {
  scheduleHeatmap($("#planned-heatmap"), t.pressure_schedule_pa, { releaseStep: t.release_step });
  if (t.executed_pressure_schedule_pa) {
    const differs = JSON.stringify(t.executed_pressure_schedule_pa) !== JSON.stringify(t.pressure_schedule_pa);
    $("#executed-note").textContent = differs ? "The executed schedule differs from the plan; the GP is fitted on what was executed." : "Executed as planned.";
    scheduleHeatmap($("#executed-heatmap"), t.executed_pressure_schedule_pa, { releaseStep: t.executed_release_step });
  } else {
    $("#executed-note").textContent = "Not executed yet.";
    $("#executed-heatmap").replaceChildren();
  }
}

function renderMeasurements(t, e) {
  const ms = t.measurements || [];
  const counted = new Set(e.objective_sources || []);
  // each source's repeats apart: the objective is made of the experiment's sources only
  const bySource = {};
  for (const m of ms) if (!m.withdrawn_at) (bySource[m.source] ||= []).push(m.value);
  $("#sources-summary").replaceChildren(...Object.entries(bySource).map(([src, vals]) => {
    const { mean, sem } = meanSem(vals);
    return el("li", { dataset: { source: src } }, `${src}: ${fmt(mean)}${sem !== null ? ` ± ${fmt(sem)}` : ""} over ${vals.length} repeat${vals.length > 1 ? "s" : ""}`,
      counted.has(src) ? el("strong", {}, " (makes the objective)") : el("span", { class: "muted" }, " (not in the objective)"));
  }));
  const rows = ms.map((m, i) => el("tr", { class: m.withdrawn_at ? "withdrawn" : "", dataset: { measurementId: m.id } },
    el("td", {}, i + 1), el("td", { class: "m-value" }, fmt(m.value, 4)), el("td", {}, m.unit),
    el("td", {}, m.source || "—"), el("td", {}, m.created_by || "—"), el("td", {}, fmtTime(m.created_at)), el("td", {}, m.note || ""),
    el("td", { class: "m-why small" }, m.withdrawn_at ? `withdrawn by ${m.withdrawn_by}, ${fmtTime(m.withdrawn_at)}: ${m.withdrawn_reason}` : (m.supersedes_id ? "a correction" : "")),
    el("td", { class: "m-actions write-only" }, m.withdrawn_at || !canWrite() ? "" : correctControls(t, m))));
  $("#measurements-table tbody").replaceChildren(...rows);
  if (!rows.length) $("#measurements-table tbody").append(el("tr", {}, el("td", { colspan: 9, class: "muted" }, "No measurement yet.")));
}

/** Correct (supersede) or withdraw one repeat, with a reason; nothing is deleted. */
function correctControls(t, m) {
  const holder = el("div", {});
  const open = (mode) => {
    const value = el("input", { class: "c-value short", "aria-label": "corrected value", inputmode: "decimal", value: mode === "correct" ? String(m.value) : "" });
    const reason = el("input", { class: "c-reason", "aria-label": "reason", placeholder: "reason (required)" });
    const error = el("p", { class: "error c-error", role: "alert" });
    const go = el("button", { class: "primary c-save", onclick: async () => {
      error.textContent = "";
      if (!reason.value.trim()) { error.textContent = "Give a reason."; return; }
      try {
        if (mode === "correct") {
          const parsed = parseValue(value.value);
          if (parsed.error) { error.textContent = `Not saved: the value ${parsed.error}.`; return; }
          await api("POST", `/api/measurements/${m.id}/supersede`, { body: { value: parsed.value, unit: m.unit, reason: reason.value.trim() } });
        } else {
          await api("POST", `/api/measurements/${m.id}/withdraw`, { body: { reason: reason.value.trim() } });
        }
        $("#trial-summary").textContent = mode === "correct" ? `Repeat corrected; trial ${t.index}'s objective recomputed.` : `Repeat withdrawn; trial ${t.index}'s objective recomputed.`;
        load(true);
      } catch (err) { error.textContent = `Not saved: ${err.message}`; }
    } }, mode === "correct" ? "Save correction" : "Withdraw");
    holder.replaceChildren(...(mode === "correct" ? [value] : []), reason, go, el("button", { onclick: () => holder.replaceChildren(...buttons()) }, "Cancel"), error);
  };
  const buttons = () => [
    el("button", { class: "c-correct", onclick: () => open("correct") }, "Correct…"),
    el("button", { class: "c-withdraw", onclick: () => open("withdraw") }, "Withdraw…")];
  holder.replaceChildren(...buttons());
  return holder;
}

function renderAudit(t) {
  const entries = t.audit;
  const rows = entries.map((a) => el("tr", {},
    el("td", {}, fmtTime(a.at)), el("td", {}, a.actor || "—"), el("td", {}, a.action),
    el("td", {}, a.before || a.after ? `${a.before ?? "—"} → ${a.after ?? "—"}` : ""),
    el("td", { class: "small" }, a.detail ? JSON.stringify(a.detail) : "")));
  $("#audit-table tbody").replaceChildren(...rows);
  if (!rows.length) $("#audit-table tbody").append(el("tr", {}, el("td", { colspan: 5, class: "muted" }, "No audit entries returned.")));
}

async function renderTrajectory(t, e) {
  const note = $("#trajectory-note");
  if (!t.has_trajectory) {
    note.textContent = "No recorded trajectory for this trial (yet). The 3D replay simulates its schedule.";
    $("#trajectory-plots").hidden = true;
    return;
  }
  try {
    const tr = await api("GET", `/api/trials/${t.id}/trajectory?format=json`);
    const time = tr.time_s;
    note.textContent = `${time.length} samples over ${fmt(time[time.length - 1], 2)} s.`;
    $("#trajectory-plots").hidden = false;
    if (tr.tip_speed_m_s) line($("#speed-plot"), time, tr.tip_speed_m_s, { title: "tip speed", ytitle: "m/s" });
    if (tr.tip_pos_m) line($("#height-plot"), time, tr.tip_pos_m.map((p) => p[2]), { title: "tip height", ytitle: "m" });
    // only the hammer task has a force plate: a throw's recording holds zeros there
    $("#force-plot").hidden = !(tr.plate_force_n && e.task === "hammer");
    if (!$("#force-plot").hidden) line($("#force-plot"), time, tr.plate_force_n, { title: "plate force", ytitle: "N" });
    else $("#force-plot").replaceChildren();
  } catch (err) {
    note.textContent = `Trajectory not shown: ${err.message}`;
  }
}

async function load(force = false) {
  try {
    const t = await api("GET", `/api/trials/${trialId}`);
    const key = `${t.status}:${t.n_measurements}:${t.updated_at}:${(t.measurements || []).length}:${(t.measurements || []).filter((m) => m.withdrawn_at).length}:${(t.twins || []).length}`;
    if (!force && key === lastKey) return;
    lastKey = key;
    const e = await api("GET", `/api/experiments/${t.experiment_id}`);
    renderFacts(t, e);
    renderSchedules(t);
    renderMeasurements(t, e);
    renderAudit(t);
    renderTrajectory(t, e);
    renderTrialActions($("#trial-actions"), t, { experiment: e, incumbentId: null, onChange: (msg) => { showError("#trial-error", null); $("#trial-summary").textContent = msg; load(true); } });
    $("#replay-button").onclick = () => openReplay(t, null);
    $("#npz-button").hidden = !t.has_trajectory;
    $("#npz-button").onclick = () => download(`/api/trials/${t.id}/trajectory?format=npz`, `trial-${t.index}-trajectory.npz`).catch((err) => showError("#trial-error", err));
    applyRole();
    showError("#trial-error", null);
  } catch (err) {
    showError("#trial-error", err);
  }
}

requireLogin().then(async () => {
  await load(true);
  setInterval(() => load(false), 3000);
});
