import { api } from "./api.js";
import { RELEASE_TASKS } from "/api-schema.js";
import { $, clearFieldErrors, el, requireLogin, showFieldErrors } from "./ui.js";

const form = $("#experiment-form");

function updateDependent() {
  const task = $("#f-task").value;
  const hw = $("#f-target").value === "hardware";
  $("#limits-fieldset").disabled = !hw;
  $("#limits-fieldset").classList.toggle("muted", !hw);
  $("#sim-prior-fieldset").disabled = !hw;
  $("#sim-prior-fieldset").classList.toggle("muted", !hw);
  const h = parseInt($("#f-horizon").value, 10) || 10;
  const release = RELEASE_TASKS.includes(task);
  const d = h + (release ? 1 : 0);
  $("#f-dim-note").textContent = `θ has D = ${d} dimensions${release ? " (H steps + the release step)" : ""}; the paper starts with D + 1 = ${d + 1} random trials.`;
  const method = $("#f-method").value;
  const bo = method.startsWith("bo-");
  $("#f-acquisition").disabled = !bo;
  const ucb = $("#f-acquisition").value === "ucb" || (method === "bo-ucb" && !$("#f-acquisition").value);
  $("#f-kappa").disabled = !bo || !ucb;
}

let initialTouched = false;
$("#f-n_initial").addEventListener("input", () => { initialTouched = true; });
$("#f-task").addEventListener("change", () => {
  $("#f-objective_unit").value = $("#f-task").value === "tip_speed" ? "m/s" : "score";
});
for (const id of ["#f-task", "#f-horizon"]) {
  $(id).addEventListener("change", () => {
    if (!initialTouched) {
      const h = parseInt($("#f-horizon").value, 10) || 10;
      $("#f-n_initial").value = h + (RELEASE_TASKS.includes($("#f-task").value) ? 1 : 0) + 1;
    }
  });
}
form.addEventListener("change", updateDependent);
form.addEventListener("input", updateDependent);

/** Numbers from the form; words for anything that is not one (shown next to its field). */
function numberField(id, apiName, errors, { integer = false, scale = 1 } = {}) {
  const raw = $(id).value.trim();
  const v = Number(raw);
  // a number input holds "" for text it cannot read (e.g. "1e"): say so, not “”
  if (raw === "" && $(id).validity && $(id).validity.badInput) { errors[apiName] = "what is typed here is not a number"; return undefined; }
  if (raw === "") { errors[apiName] = "is empty: type a number"; return undefined; }
  if (!Number.isFinite(v)) { errors[apiName] = `“${raw}” is not a number`; return undefined; }
  if (integer && !Number.isInteger(v)) { errors[apiName] = `${raw} is not a whole number`; return undefined; }
  return v * scale;
}

function collect() {
  const errors = {};
  const task = $("#f-task").value;
  const target = $("#f-target").value;
  const horizon = numberField("#f-horizon", "horizon", errors, { integer: true });
  const body = {
    name: $("#f-name").value.trim(),
    task, target,
    sim_preset: $("#f-sim_preset").value,
    command_hold: $("#f-command_hold").value,
    levels: numberField("#f-levels", "levels", errors, { integer: true }),
    horizon,
    with_release: RELEASE_TASKS.includes(task),
    method: $("#f-method").value,
    acquisition: $("#f-acquisition").disabled ? null : ($("#f-acquisition").value || null),
    kappa: $("#f-kappa").disabled ? null : numberField("#f-kappa", "kappa", errors),
    objective_unit: $("#f-objective_unit").value,
    n_initial: numberField("#f-n_initial", "n_initial", errors, { integer: true }),
    budget: numberField("#f-budget", "budget", errors, { integer: true }),
    seed: numberField("#f-seed", "seed", errors, { integer: true }),
    notes: $("#f-notes").value,
  };
  // imported observations always count: they are what the operator chose to import
  if ($("#f-objective_sources").value) body.objective_sources = [$("#f-objective_sources").value, "imported"];
  if (target === "hardware" && $("#f-sim_prior").value) body.sim_prior_experiment_id = Number($("#f-sim_prior").value);
  if (!body.name) errors.name = "give the experiment a name";
  // the API's rules, in the form's own words and units
  if (body.method.startsWith("bo-") && Number.isInteger(body.n_initial) && Number.isInteger(body.budget) && body.n_initial > body.budget) {
    errors.n_initial = `${body.n_initial} initial random trials do not fit in a budget of ${body.budget} trials`;
  }
  if (Number.isInteger(body.n_initial) && body.n_initial < 2) errors.n_initial = "at least 2 initial trials";
  if (Number.isInteger(body.budget) && body.budget < 1) errors.budget = "at least 1 trial";
  if (target === "hardware") {
    const parts = $("#f-nominal").value.split(/[,\s]+/).filter(Boolean);
    const nominal = parts.map(Number);
    if (!parts.length || nominal.some((v) => !Number.isFinite(v))) {
      errors.nominal_pa = "nominal pressures must be numbers in kPa";
    } else if (nominal.length !== 1 && nominal.length !== 12) {
      errors.nominal_pa = `give 1 or 12 nominal pressures, not ${nominal.length}`;
    }
    body.limits = {
      nominal_pa: nominal.length === 1 ? nominal[0] * 1000 : nominal.map((v) => v * 1000),
      max_step_pa: numberField("#f-max_step", "max_step_pa", errors, { scale: 1000 }),
      source_pa: numberField("#f-source", "source_pa", errors, { scale: 1000 }),
    };
    const step = body.limits.max_step_pa / 1000;
    const source = body.limits.source_pa / 1000;
    if (Number.isFinite(step) && step <= 0) errors.max_step_pa = "must be more than 0 kPa";
    if (Number.isFinite(source) && source <= 0) errors.source_pa = "must be more than 0 kPa";
    if (!errors.nominal_pa && Number.isFinite(step) && Number.isFinite(source) && step > 0) {
      const bad = nominal.find((p) => p - step < 0 || p + step > source);
      if (bad !== undefined) errors.nominal_pa = `${bad} kPa ± ${step} kPa spans ${bad - step} to ${bad + step} kPa, outside 0 to the ${source} kPa source`;
    }
  }
  return { body, errors };
}

form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  clearFieldErrors(form);
  $("#form-error").textContent = "";
  const { body, errors } = collect();
  if (Object.keys(errors).length) {
    showFieldErrors(form, errors);
    $("#form-error").textContent = "Fix the fields marked in red.";
    return;
  }
  const button = $("#create-button");
  button.disabled = true;
  try {
    const exp = await api("POST", "/api/experiments", { body });
    location.href = `/experiments/${exp.id}`;
  } catch (err) {
    // the robot's ceilings come back as "limits: …": put each next to its own kPa field
    const placed = placeServerMessage(err.fields.limits ? `limits: ${err.fields.limits}` : err.message);
    if (err.fields.limits && Object.keys(placed).length) delete err.fields.limits;
    if (!Object.keys(err.fields).length || Object.keys(placed).length) err.fields = { ...err.fields, ...placed };
    const unplaced = showFieldErrors(form, err.fields);
    $("#form-error").textContent = Object.keys(err.fields).length
      ? ["The server refused some fields (marked in red).", ...unplaced].join("\n")
      : err.message;
  } finally {
    button.disabled = false;
  }
});

/** A server refusal without a field (e.g. the robot's ceilings, in kPa) next to its field. */
function placeServerMessage(message) {
  const m = String(message || "");
  const rules = [
    [/source pressure/, "source_pa"], [/maximum step|max step/, "max_step_pa"],
    [/^limits:.*(nominal|chamber)/, "nominal_pa"], [/^n_initial/, "n_initial"], [/budget/, "budget"],
    [/^optimizer settings/, "method"], [/^sim_preset/, "sim_preset"],
  ];
  for (const [re, field] of rules) if (re.test(m)) return { [field]: m.replace(/^(limits|n_initial|budget): /, "") };
  return {};
}

requireLogin().then((me) => {
  if (me.role !== "operator") {
    form.replaceWith(el("p", { class: "error" }, `You are logged in as a ${me.role}: only operators can create experiments.`));
    return;
  }
  updateDependent();
  loadSimExperiments();
});

/** The sim experiments a hardware experiment may take as its sim prior (the server checks
 * that task, policy and hold match, and says what differs). */
async function loadSimExperiments() {
  try {
    const all = await api("GET", "/api/experiments");
    $("#f-sim_prior").append(...all.filter((x) => x.target === "sim").map((x) => el("option", { value: x.id },
      `#${x.id} ${x.name} (${x.task}, P = ${x.levels}, H = ${x.horizon}${x.with_release ? " + release" : ""}, ${x.command_hold} hold)`)));
  } catch (err) {
    $("#f-sim_prior").title = `Sim experiments not listed: ${err.message}`;
  }
}
