import { api } from "./api.js";
import { $, badge, el, fmt, fmtTime, requireLogin, showError } from "./ui.js";

/** A count that needs the operator: a link to the experiment, highlighted when not zero. */
function needs(exp, n, what) {
  return el("td", { class: n ? "needs" : "muted", dataset: { what } },
    n ? el("a", { href: `/experiments/${exp.id}` }, String(n)) : "0");
}

function row(exp) {
  const counts = exp.status_counts;
  const done = counts.completed ?? 0;
  return el("tr", { class: "clickable", dataset: { id: exp.id }, onclick: () => { location.href = `/experiments/${exp.id}`; } },
    el("td", {}, exp.id),
    el("td", {}, el("a", { href: `/experiments/${exp.id}` }, exp.name || `experiment ${exp.id}`)),
    el("td", {}, badge(exp.status), exp.budget_reached ? el("div", { class: "small budget-reached" }, "budget reached") : null),
    el("td", {}, exp.task),
    el("td", {}, exp.target),
    needs(exp, counts.awaiting_confirmation ?? 0, "awaiting_confirmation"),
    needs(exp, exp.n_awaiting_measurement, "awaiting_measurement"),
    el("td", { class: "done" }, `${done} / ${exp.budget ?? "∞"}`),
    el("td", {}, fmt(exp.best_objective)),
    el("td", {}, fmtTime(exp.created_at)));
}

let lastKey = null;

async function load() {
  const tbody = $("#experiments-table tbody");
  try {
    const experiments = await api("GET", "/api/experiments");
    const key = JSON.stringify(experiments.map((e) => [e.id, e.version, e.status, e.n_awaiting_measurement, e.status_counts]));
    if (key !== lastKey) {
      lastKey = key;
      $("#list-empty").hidden = experiments.length > 0;
      tbody.replaceChildren(...experiments.map(row));
    }
    $("#list-live").textContent = "live";
    showError("#list-error", null);
  } catch (err) {
    $("#list-live").textContent = `updates paused: ${err.message}`;
  }
}

requireLogin().then(async () => {
  await load();
  setInterval(load, 2000); // the list follows what needs the operator, live
});
