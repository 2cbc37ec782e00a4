// The sim prior and the sim twins on the pages: what a suggestion leaned on, the twin's
// prediction beside the GP's at the safety gate, and the experiment's hardware-vs-twin card.
import { api } from "./api.js";
import { hardwareVsTwin } from "./plots.js";
import { $, canWrite, el, fmt, fmtPm } from "./ui.js";

const HOLD = { zero: "zero hold", linear: "linear hold" };

/** A trial's suggestion_basis ({mode, n_prior, n_own, step, task_correlation, sim_experiment_id}) in words. */
export function basisText(basis) {
  if (!basis) return "—";
  const own = `${basis.n_own} hardware trial${basis.n_own === 1 ? "" : "s"}`;
  const from = basis.sim_experiment_id ? ` (sim experiment ${basis.sim_experiment_id})` : "";
  const sims = `${basis.n_prior} sim trial${basis.n_prior === 1 ? "" : "s"}${from}`;
  if (basis.step === "prior") return `one of the sim prior's best θ, from ${sims}`;
  if (basis.step === "design") return basis.mode ? `the initial design (sim prior: ${sims}, ${basis.mode})` : "the initial design (random, no model yet)";
  if (basis.mode === "multitask") {
    const rho = basis.task_correlation !== null && basis.task_correlation !== undefined ? `; sim ↔ hardware correlation ${fmt(basis.task_correlation, 2)}` : "";
    return `a multi-task GP over ${sims} and ${own}${rho}`;
  }
  if (basis.mode === "warmstart") return `the model of ${own} (its design began with the best of ${sims})`;
  return `the model of ${own} (no sim prior)`;
}

/** A TwinRead in words: its prediction, peak tip speed and bend-limit hits. */
export function twinText(twin, unit = "") {
  if (!twin) return "being simulated…";
  const how = `${twin.sim_preset} preset, ${HOLD[twin.command_hold] || twin.command_hold}`;
  if (twin.status !== "done") return `failed (${how}): ${twin.error}`;
  const hits = twin.bend_limit_hits || [];
  const bends = hits.length ? `bend limit hit at joint ${hits.join(", ")}` : "no bend limit hit";
  return `${fmt(twin.predicted_objective)} ${unit} (${how}); tip speed ${fmt(twin.predicted_tip_speed)} m/s; ${bends}`;
}

/**
 * The GP's and the sim twin's predictions side by side, for the safety gate. The twin is made
 * by the server moments after the trial: poll until it is there (or this box is gone).
 */
export function gatePredictions(trial, experiment) {
  const unit = experiment.objective_unit || "";
  const gp = trial.predicted_mean !== null && trial.predicted_mean !== undefined
    ? `${fmtPm(trial.predicted_mean, trial.predicted_std)} ${unit} (mean ± std)` : "none (initial design, or not a BO experiment)";
  const twinLine = el("span", { id: "gate-twin" }, "being simulated…");
  const line = (label, value) => el("p", { class: "small gate-line" }, el("strong", {}, `${label}: `), value);
  const box = el("div", { class: "gate-predictions", id: "gate-predictions" },
    line("GP predicts", el("span", { id: "gate-gp" }, gp)),
    line("Sim twin predicts", twinLine),
    line("Suggested from", el("span", { id: "gate-basis" }, basisText(trial.suggestion_basis))));
  const poll = async () => {
    if (!box.isConnected && box.dataset.started) return;
    box.dataset.started = "1";
    try {
      const twins = await api("GET", `/api/trials/${trial.id}/twins`);
      const planned = twins.find((x) => x.kind === "planned");
      if (planned) { twinLine.textContent = twinText(planned, unit); return; }
    } catch (err) {
      twinLine.textContent = `not shown: ${err.message}`;
      return;
    }
    setTimeout(poll, 1000);
  };
  setTimeout(poll, 0);
  return box;
}

/** The experiment page's card: the linked sim experiment (link, unlink, start one) and the
 * hardware-vs-twin plot with the discrepancy. Hidden for sim experiments. */
export async function renderSimPrior(experiment, onChange) {
  const card = $("#sim-prior-card");
  if (!card) return;
  card.hidden = experiment.target !== "hardware";
  if (card.hidden) return;
  try {
    const [prior, rows] = await Promise.all([
      api("GET", `/api/experiments/${experiment.id}/sim-prior`),
      api("GET", `/api/experiments/${experiment.id}/twins`),
    ]);
    $("#sim-prior-state").replaceChildren(prior.sim_experiment_id
      ? el("span", {}, "Sim prior: ", el("a", { href: `/experiments/${prior.sim_experiment_id}` }, `${prior.sim_experiment_name} (#${prior.sim_experiment_id})`),
        `, ${prior.sim_preset} preset: ${prior.n_scored} scored sim trial${prior.n_scored === 1 ? "" : "s"}${prior.n_pending ? `, ${prior.n_pending} still to run` : ""}${prior.best_objective !== null ? `, best ${fmt(prior.best_objective)}` : ""}. They never count against this experiment's budget.`)
      : "No sim prior: the optimiser learns from the hardware trials alone.");
    $("#sim-twin-note").textContent = `Each hardware trial's sim twin runs exactly its schedule (${prior.twin_preset} preset, ${HOLD[experiment.command_hold] || experiment.command_hold}, scored by the ${prior.twin_objective_rule} rule).`;
    const shown = hardwareVsTwin($("#twin-plot"), rows, experiment.objective_unit || "");
    $("#twin-empty").hidden = shown > 0;
    if (canWrite()) await linkControls(experiment, prior, onChange);
  } catch (err) {
    $("#sim-prior-state").textContent = `Sim prior not shown: ${err.message}`;
  }
}

async function linkControls(experiment, prior, onChange) {
  const holder = $("#sim-prior-controls");
  if (holder.contains(document.activeElement)) return; // the operator is using them
  const error = el("p", { class: "error", id: "sim-prior-error", role: "alert" });
  const act = async (method, path, body, done) => {
    error.textContent = "";
    try {
      await api(method, path, body === undefined ? {} : { body });
      onChange(done);
    } catch (err) { error.textContent = `Refused: ${err.message}`; }
  };
  if (prior.sim_experiment_id) {
    holder.replaceChildren(el("button", { id: "sim-prior-unlink", onclick: () => act("DELETE", `/api/experiments/${experiment.id}/sim-prior`, undefined, "Sim prior unlinked.") }, "Unlink the sim prior"), error);
    return;
  }
  const all = await api("GET", "/api/experiments");
  const pick = el("select", { id: "sim-prior-select", "aria-label": "sim experiment to link" },
    ...all.filter((x) => x.target === "sim").map((x) => el("option", { value: x.id }, `#${x.id} ${x.name} (${x.task}, P = ${x.levels}, H = ${x.horizon}, ${x.command_hold} hold)`)));
  const n = el("input", { id: "sim-prior-n", type: "number", min: 1, max: 100, value: 24, class: "tiny", "aria-label": "sim trials to queue" });
  holder.replaceChildren(
    el("label", { class: "inline" }, "Link ", pick),
    el("button", { id: "sim-prior-link", disabled: !pick.options.length, onclick: () => act("PUT", `/api/experiments/${experiment.id}/sim-prior`, { sim_experiment_id: Number(pick.value) }, "Sim prior linked.") }, "Link"),
    el("span", { class: "muted" }, " or "),
    el("button", { id: "sim-prior-start", onclick: () => act("POST", `/api/experiments/${experiment.id}/sim-prior/start`, { n_trials: Number(n.value) }, "Sim prior started: its trials are queued for the sim workers.") }, "Start one"),
    el("label", { class: "inline" }, " with ", n, " sim trials for the sim workers"), error);
}
