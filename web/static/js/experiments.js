import { api } from "./api.js";
import { $, badge, el, fmt, fmtTime, requireLogin, showError } from "./ui.js";

/** Trials done and best so far, from the experiment's own summary (ExperimentRead). */
function progress(exp) {
  return { done: exp.status_counts.completed ?? 0, best: exp.best_objective };
}

async function load() {
  await requireLogin();
  const tbody = $("#experiments-table tbody");
  try {
    const experiments = await api("GET", "/api/experiments");
    $("#list-empty").hidden = experiments.length > 0;
    tbody.replaceChildren();
    for (const exp of experiments) {
      const { done, best } = progress(exp);
      const row = el("tr", { class: "clickable", dataset: { id: exp.id }, onclick: () => { location.href = `/experiments/${exp.id}`; } },
        el("td", {}, exp.id),
        el("td", {}, el("a", { href: `/experiments/${exp.id}` }, exp.name || `experiment ${exp.id}`)),
        el("td", {}, badge(exp.status)),
        el("td", {}, exp.task),
        el("td", {}, exp.target),
        el("td", {}, `${done} / ${exp.budget ?? "∞"}`),
        el("td", {}, fmt(best)),
        el("td", {}, fmtTime(exp.created_at)));
      tbody.append(row);
    }
  } catch (err) {
    showError("#list-error", err);
  }
}

load();
