import { api } from "./api.js";
import { $, badge, el, fmt, fmtTime, requireLogin, showError } from "./ui.js";

function listOf(answer) {
  return Array.isArray(answer) ? answer : (answer && (answer.items || answer.experiments)) || [];
}

/** Trials done and best so far: from the experiment's own summary, else from its trials. */
async function progress(exp) {
  const done = exp.status_counts ? (exp.status_counts.completed ?? 0) : undefined;
  const best = exp.best_objective ?? exp.best_so_far;
  if (done !== undefined && best !== undefined) return { done, best };
  const trials = listOf(await api("GET", `/api/experiments/${exp.id}/trials`));
  const completed = trials.filter((t) => t.status === "completed" && t.objective !== null);
  return {
    done: completed.length,
    best: completed.length ? Math.max(...completed.map((t) => t.objective)) : null,
  };
}

async function load() {
  await requireLogin();
  const tbody = $("#experiments-table tbody");
  try {
    const experiments = listOf(await api("GET", "/api/experiments"));
    $("#list-empty").hidden = experiments.length > 0;
    tbody.replaceChildren();
    for (const exp of experiments) {
      const doneCell = el("td", {}, "…");
      const bestCell = el("td", {}, "…");
      const row = el("tr", { class: "clickable", dataset: { id: exp.id }, onclick: () => { location.href = `/experiments/${exp.id}`; } },
        el("td", {}, exp.id),
        el("td", {}, el("a", { href: `/experiments/${exp.id}` }, exp.name || `experiment ${exp.id}`)),
        el("td", {}, badge(exp.status)),
        el("td", {}, exp.task),
        el("td", {}, exp.target),
        doneCell, bestCell,
        el("td", {}, fmtTime(exp.created_at)));
      tbody.append(row);
      progress(exp).then(({ done, best }) => {
        doneCell.textContent = `${done} / ${exp.budget ?? "∞"}`;
        bestCell.textContent = fmt(best);
      }).catch((err) => { doneCell.textContent = "?"; bestCell.textContent = err.message; });
    }
  } catch (err) {
    showError("#list-error", err);
  }
}

load();
