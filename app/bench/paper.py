"""The paper's grid and tables: which cells to run, and ``paper.md`` with handful's number beside
each of the paper's.

A *cell* is (task, method, P, trials): one number of the paper's tables, the mean ± std over
seeds of the best objective after ``trials`` trials. Cells that share (task, method, P) share
their runs: one run per seed, as long as the largest trial count asked of them.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.bench.specs import SWEEP_METHODS, RunSpec, check_rl_settings
from app.bench.stats import best_at, welch_p
from app.optim import DEFAULT_METHOD, SettingsError
from app.optim.baselines import PAPER_CEM_INIT_STD
from app.rl.settings import RL_METHODS

PAPER_LEVELS = (2, 5, 7, 10)
PAPER_TRIALS = (100, 500, 10_000)
PAPER_TASKS = ("throw", "hammer")
#: the paper's methods in its tables' order, with the names its tables print
PAPER_METHODS = {
    "bo-ucb": "BayesOpt-UCB (κ = 0.9)",
    "bo-lei": "BayesOpt-LEI",
    "cem": "CEM",
    "random": "Random search",
}
#: trial counts the paper reports per method (BO stops at 500)
METHOD_TRIALS = {"bo-ucb": (100, 500), "bo-lei": (100, 500), "cem": PAPER_TRIALS}
METHOD_TRIALS["random"] = PAPER_TRIALS
METHOD_TRIALS[DEFAULT_METHOD] = (100, 500)
#: ``handful bench paper --bo-fit NAME``: the settings every BO method of the grid gets.
#: full: the paper's (every GP fitted from scratch, BoTorch's posterior); warm: fits from the
#: last anchor's hyperparameters (``app.optim.bo.anchor_size``); fast: no fit between
#: anchors (their hyperparameters, conditioned on all data) and the cached exact posterior
#: in the acquisition search (``app.optim.posterior``).
BO_FITS: dict[str, dict[str, Any]] = {
    "full": {"fit_mode": "full"},
    "warm": {"fit_mode": "warm"},
    "fast": {"fit_mode": "warm", "warm_maxiter": 0, "acq_posterior": "cached"},
}
REDQ_METHODS = {"redq": "REDQ", "redq-joints": "REDQ with approximate joint states"}
REDQ_TRIALS = (250, 500, 10_000)

# The paper's Tables "Simulated throwing / hammering performance": best so far, mean ± std over
# 5 seeds; (task, method, trials) → one (mean, std) per P in PAPER_LEVELS.
_T = tuple[tuple[float, float], ...]
PAPER_TABLES: dict[tuple[str, str, int], _T] = {
    ("throw", "bo-ucb", 100): ((28.526, 4.025), (25.959, 2.86), (21.842, 7.434), (21.235, 6.135)),
    ("throw", "bo-ucb", 500): ((34.176, 5.417), (29.089, 3.664), (26.016, 7.86), (28.434, 5.998)),
    ("throw", "bo-lei", 100): ((30.369, 6.864), (30.345, 6.554), (32.208, 3.709), (31.506, 4.541)),
    ("throw", "bo-lei", 500): ((37.697, 1.679), (38.285, 2.581), (40.878, 1.375), (40.171, 1.834)),
    ("throw", "cem", 100): ((28.937, 2.758), (20.730, 0.918), (19.724, 1.987), (20.629, 2.061)),
    ("throw", "cem", 500): ((33.653, 1.788), (24.03, 2.626), (22.731, 2.793), (22.867, 3.424)),
    # as printed: "41.942 ± 41.9" at P = 2 (surely a typo for a std near 2; no ⚠ can show there)
    ("throw", "cem", 10_000): ((41.942, 41.9), (38.931, 1.897), (36.939, 2.756), (35.412, 2.407)),
    ("throw", "random", 100): ((27.435, 1.349), (22.125, 1.763), (19.167, 1.795), (20.614, 3.245)),
    ("throw", "random", 500): ((30.354, 1.835), (23.840, 1.693), (22.325, 1.074), (22.269, 1.921)),
    ("throw", "random", 10_000):
        ((34.131, 1.473), (28.834, 1.456), (26.027, 0.493), (26.634, 2.962)),
    ("hammer", "bo-ucb", 100): ((1.137, 0.476), (1.342, 0.624), (2.588, 1.019), (1.601, 1.294)),
    ("hammer", "bo-ucb", 500): ((1.775, 0.403), (2.552, 0.7077), (2.719, 1.06), (2.278, 0.9145)),
    ("hammer", "bo-lei", 100): ((2.566, 0.666), (1.923, 0.938), (2.662, 0.964), (2.839, 0.833)),
    ("hammer", "bo-lei", 500): ((3.387, 0.3702), (4.217, 1.097), (3.534, 0.1906), (3.541, 0.42)),
    ("hammer", "cem", 100): ((1.182, 0.473), (1.140, 0.151), (1.157, 0.184), (1.164, 0.319)),
    ("hammer", "cem", 500): ((1.493, 0.271), (1.378, 0.268), (1.303, 0.287), (1.232, 0.318)),
    ("hammer", "cem", 10_000): ((2.174, 0.798), (2.026, 0.603), (2.342, 0.635), (2.171, 0.536)),
    ("hammer", "random", 100): ((1.441, 0.621), (1.137, 0.135), (1.150, 0.073), (1.076, 0.118)),
    ("hammer", "random", 500): ((2.030, 0.215), (1.438, 0.345), (1.208, 0.164), (1.236, 0.131)),
    ("hammer", "random", 10_000): ((3.002, 0.541), (2.441, 0.233), (2.369, 0.082), (2.281, 0.303)),
}  # fmt: skip
# The paper's REDQ table (no discretisation): (task, method, trials) → (mean, std).
PAPER_REDQ: dict[tuple[str, str, int], tuple[float, float]] = {
    ("throw", "redq", 250): (14.782, 2.944), ("hammer", "redq", 250): (0.116, 0.07),
    ("throw", "redq", 500): (27.362, 0.862), ("hammer", "redq", 500): (1.411, 0.125),
    ("throw", "redq", 10_000): (33.016, 0.975), ("hammer", "redq", 10_000): (2.344, 0.06),
    ("throw", "redq-joints", 250): (15.719, 2.771), ("hammer", "redq-joints", 250): (0.239, 0.209),
    ("throw", "redq-joints", 500): (30.35, 1.812), ("hammer", "redq-joints", 500): (2.098, 0.421),
    ("throw", "redq-joints", 10_000): (37.72, 2.223),
    ("hammer", "redq-joints", 10_000): (3.12, 0.065),
}  # fmt: skip


def paper_value(task: str, method: str, levels: int, trials: int) -> tuple[float, float] | None:
    """The paper's (mean, std) for a cell, or None where the paper has no such number."""
    row = PAPER_TABLES.get((task, method, trials))
    if row is not None and levels in PAPER_LEVELS:
        return row[PAPER_LEVELS.index(levels)]
    return PAPER_REDQ.get((task, method, trials))


@dataclass(frozen=True, order=True)
class Cell:
    """One number of the tables: the best objective of ``method`` after ``trials`` trials on
    ``task`` with P = ``levels`` (0 for REDQ, which acts on continuous pressures)."""

    task: str
    method: str
    levels: int
    trials: int


def grid(available: Sequence[str] = SWEEP_METHODS) -> list[Cell]:
    """Every cell of the paper's two tables, handful's default method at 100 and 500 trials, and
    REDQ's table when ``available`` has REDQ."""
    cells = [
        Cell(task, method, p, n)
        for task in PAPER_TASKS
        for method in (*PAPER_METHODS, DEFAULT_METHOD)
        for p in PAPER_LEVELS
        for n in METHOD_TRIALS[method]
    ]
    cells += [
        Cell(task, method, 0, n)
        for task in PAPER_TASKS
        for method in REDQ_METHODS
        if method in available
        for n in REDQ_TRIALS
    ]
    return cells


_TERM = re.compile(r"^\s*(task|method|p|trials)\s*(<=|>=|=|<|>)\s*(.+?)\s*$", re.IGNORECASE)
_OPS = {
    "=": lambda a, b: a in b,
    "<=": lambda a, b: a <= b[0],
    ">=": lambda a, b: a >= b[0],
    "<": lambda a, b: a < b[0],
    ">": lambda a, b: a > b[0],
}


def _number(key: str, text: str) -> int:
    t = text.strip().lower().replace("_", "").replace(",", "")
    scale = 1000 if t.endswith("k") else 1
    try:
        return int(t[:-1] if scale > 1 else t) * scale
    except ValueError:
        raise SettingsError(f"{key} takes whole numbers, got {text!r}") from None


def parse_term(term: str) -> tuple[str, str, list[Any]]:
    """``"P=2,5"``, ``"trials<=500"``, ``"task=throw"``, ``"method=bo-lei,cem"`` → (key, op,
    values), checked against the paper's grid: one clear line for anything outside it."""
    m = _TERM.match(term)
    if not m:
        raise SettingsError(
            f"cannot read the cell filter {term!r}; write e.g. P=7, P=2,5, trials<=500, "
            "task=throw or method=bo-lei,cem"
        )
    key, op, raw = m.group(1).lower(), m.group(2), m.group(3)
    if op != "=" and key in ("task", "method"):
        raise SettingsError(f"{key} takes '=' (e.g. {key}=...), got {term!r}")
    if op != "=" and "," in raw:
        raise SettingsError(f"{term!r}: a comparison takes one value")
    values: list[Any]
    if key == "p":
        values = [_number("P", v) for v in raw.split(",")]
        if op == "=":
            bad = [v for v in values if v not in PAPER_LEVELS]
            if bad:
                raise SettingsError(
                    f"P={bad[0]} is not in the paper's grid (P is one of "
                    f"{', '.join(map(str, PAPER_LEVELS))})"
                )
    elif key == "trials":
        values = [_number("trials", v) for v in raw.split(",")]
        top = max(max(PAPER_TRIALS), max(REDQ_TRIALS))
        for v in values:
            if v > top or v < 1:
                raise SettingsError(
                    f"trials={v:,}: the paper's grid has 100, 250 (REDQ), 500 and 10K trials "
                    "and nothing above 10K"
                )
            if op == "=" and v not in (*PAPER_TRIALS, *REDQ_TRIALS):
                raise SettingsError(
                    f"trials={v:,} is not in the paper's grid (100, 250 for REDQ, 500, 10K)"
                )
    elif key == "task":
        values = [v.strip() for v in raw.split(",")]
        for v in values:
            if v not in PAPER_TASKS:
                raise SettingsError(f"task {v!r} is not in the paper's tables (throw, hammer)")
    else:
        values = [v.strip() for v in raw.split(",")]
        known = (*PAPER_METHODS, DEFAULT_METHOD, *REDQ_METHODS)
        for v in values:
            if v not in known:
                raise SettingsError(
                    f"unknown method {v!r}; the paper's grid has {', '.join(known)}"
                )
    return ("levels" if key == "p" else key), op, values


def select(cells: Iterable[Cell], terms: Sequence[str]) -> list[Cell]:
    """The cells that pass every term (terms are ANDed; see ``parse_term``)."""
    parsed = [parse_term(t) for t in terms]
    out = []
    for c in cells:
        if all(_OPS[op](getattr(c, key), vals) for key, op, vals in parsed):
            out.append(c)
    return sorted(set(out))


def run_specs(
    cells: Sequence[Cell],
    *,
    seeds: int,
    preset: str,
    command_hold: str,
    objective_rule: str,
    bo_settings: dict[str, Any] | None = None,
    rl_settings: dict[str, Any] | None = None,
) -> list[RunSpec]:
    """One run per (task, method, P, seed) of ``cells``, as long as its largest cell.

    CEM runs with the paper's initial spread (``PAPER_CEM_INIT_STD``);
    ``bo_settings`` go to every BO method (e.g. ``{"fit_mode": "warm"}``), ``rl_settings`` to
    REDQ (checked here: a bad one raises SettingsError); a run's cache key carries them (but
    ``EXECUTION_SETTINGS``), so runs with other settings never mix.
    """
    if seeds < 1:
        raise SettingsError(f"seeds must be ≥ 1, got {seeds}")
    longest: dict[tuple[str, str, int], int] = {}
    for c in cells:
        k = (c.task, c.method, c.levels)
        longest[k] = max(longest.get(k, 0), c.trials)
    specs = []
    for (task, method, p), budget in longest.items():
        if method in RL_METHODS:
            settings = dict(rl_settings or {})
            check_rl_settings(method, settings)
        elif method == "cem":
            settings = {"init_std": PAPER_CEM_INIT_STD}  # the paper's CEM (its constant's note)
        else:
            settings = dict(bo_settings or {}) if method.startswith("bo-") else {}
        for s in range(seeds):
            specs.append(
                RunSpec(
                    method,
                    task,
                    p,
                    s,
                    budget,
                    preset,
                    settings=settings,
                    command_hold=command_hold,
                    objective_rule=objective_rule,
                )
            )
    return specs


def _fmt(mean: float, std: float, digits: int) -> str:
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def cell_values(rows: Sequence[dict[str, Any]], cells: Sequence[Cell]) -> dict[Cell, list[float]]:
    """Cell → best-so-far after its trials, one value per seed that reached them."""
    budgets = sorted({c.trials for c in cells})
    table = best_at(rows, budgets)
    return {c: table.get((c.task, c.method, c.levels, c.trials), []) for c in cells}


def cell_cost_s(rows: Sequence[dict[str, Any]], cell: Cell) -> list[float]:
    """Measured wall seconds of each seed's first ``cell.trials`` trials (suggest + episode)."""
    per_seed: dict[int, list[float]] = {}
    for r in rows:
        if (r["task"], r["method"], r["levels"]) == (cell.task, cell.method, cell.levels):
            per_seed.setdefault(r["seed"], []).append(r["wall_s"])
    return [sum(v[: cell.trials]) for v in per_seed.values() if len(v) >= cell.trials]


def paper_markdown(
    rows: Sequence[dict[str, Any]],
    chosen: Sequence[Cell],
    *,
    header: Sequence[str],
    available: Sequence[str] = SWEEP_METHODS,
) -> str:
    """``paper.md``: the paper's two tables (and REDQ's) with handful's number beside each of
    the paper's: mean ± std (ddof 0) over the seeds run, the seed count, and ⚠ where the two
    means differ by more than two of the paper's standard deviations. Cells not chosen or not
    yet run say so; nothing is extrapolated. ``rows`` may hold more runs than ``chosen``'s
    (every run stored): their cells are shown too."""
    values = cell_values(rows, grid(available))
    chosen_set = set(chosen)
    lines = ["# The paper's tables, reproduced by handful", "", *header, ""]
    lines += [
        "Each cell: **handful** mean ± std (n seeds) | paper mean ± std. ⚠: the means differ by "
        "more than two of the paper's standard deviations. *not run*: the cell was not asked "
        "for (`--cells`) and no stored run has reached it; *unfinished*: asked for, but no seed "
        "has reached its trial count yet.",
        "",
    ]
    names = {**PAPER_METHODS, DEFAULT_METHOD: f"handful default ({DEFAULT_METHOD})"}
    for task, title in (("throw", "Throwing"), ("hammer", "Hammering")):
        digits = 2 if task == "throw" else 3
        lines += [
            f"## {title}: best objective so far",
            "",
            "| Method | Trials | "
            + " | ".join(f"P={p} handful | P={p} paper" for p in PAPER_LEVELS)
            + " |",
            "|---|---:|" + "---:|---:|" * len(PAPER_LEVELS),
        ]
        for method, name in names.items():
            for n in METHOD_TRIALS[method]:
                out = []
                for p in PAPER_LEVELS:
                    c = Cell(task, method, p, n)
                    ref = paper_value(task, method, p, n)
                    out.append(_ours(values.get(c, []), ref, c in chosen_set, digits))
                    out.append("–" if ref is None else _fmt(*ref, digits))
                label = f"{n // 1000}K" if n >= 1000 else str(n)
                lines.append(f"| {name} | {label} | " + " | ".join(out) + " |")
        lines.append("")
    lines += [
        "## REDQ (continuous pressures, no P): best objective so far",
        "",
        "| Agent | Trials | throw handful | throw paper | hammer handful | hammer paper |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for method, name in REDQ_METHODS.items():
        for n in REDQ_TRIALS:
            out = []
            for task in PAPER_TASKS:
                c = Cell(task, method, 0, n)
                ref = PAPER_REDQ[(task, method, n)]
                digits = 2 if task == "throw" else 3
                if method not in available:
                    out.append("*not in this build*")
                else:
                    out.append(_ours(values.get(c, []), ref, c in chosen_set, digits))
                out.append(_fmt(*ref, digits))
            label = f"{n // 1000}K" if n >= 1000 else str(n)
            lines.append(f"| {name} | {label} | " + " | ".join(out) + " |")
    lines += ["", *default_vs_peers_markdown(rows)]
    lines += ["", "## What each cell cost (measured)", ""]
    lines += [
        "Wall seconds per seed for the cell's trials (suggestion + episode, the run's own "
        "clock), mean over the seeds that reached it.",
        "",
        "| Task | Method | P | Trials | seeds | s per seed |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for c in sorted(chosen_set | {c for c, v in values.items() if v}):
        cost = cell_cost_s(rows, c)
        if cost:
            lines.append(
                f"| {c.task} | {c.method} | {c.levels or '–'} | {c.trials} | {len(cost)} "
                f"| {float(np.mean(cost)):.1f} |"
            )
    lines += ["", *projection_markdown(rows, available=available)]
    return "\n".join(lines) + "\n"


def default_vs_peers(
    rows: Sequence[dict[str, Any]], budgets: Sequence[int] = (100, 500)
) -> list[dict[str, Any]]:
    """handful's default method against every other method run, per (task, P, trials): means
    over seeds, their difference and Welch's two-sided p (None with < 2 seeds a side). REDQ
    (no P) is set against the default at every P; the default's 500 trials also against CEM's
    and random search's 10K (``peer_trials``)."""
    table = best_at(rows, sorted({*budgets, 10_000}))
    out = []
    for (task, method, p, n), ref in sorted(table.items()):
        if method != DEFAULT_METHOD or n not in budgets:
            continue
        peers = [(m, q, k) for (t, m, q, k) in table if t == task and m != DEFAULT_METHOD]
        for m, q, k in sorted(peers):
            if not ((k == n and q in (p, 0)) or (n == 500 and k == 10_000 and q == p)):
                continue
            peer = table[(task, m, q, k)]
            pval = welch_p(ref, peer)
            out.append(
                {
                    "task": task,
                    "levels": p,
                    "trials": n,
                    "peer": m,
                    "peer_trials": k,
                    "ref": ref,
                    "peer_values": peer,
                    "diff": float(np.mean(ref) - np.mean(peer)),
                    "p": pval,
                }
            )
    return out


def default_vs_peers_markdown(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The section of paper.md that checks the default method's goal: ahead of every peer after
    100 and 500 trials in every cell run, p < 0.05 where it claims a lead."""
    lines = [
        f"## handful's default ({DEFAULT_METHOD}) against every peer",
        "",
        "Best so far after the same trials (the default's 500 also against 10K of CEM and random "
        "search); REDQ has no P and is set against each P. Welch's two-sided t-test over seeds. "
        "*lead*: ahead with p < 0.05; *ahead*: ahead, not significant; *behind*: behind.",
        "",
    ]
    found = default_vs_peers(rows)
    if not found:
        return [*lines, "No cell has runs of the default and a peer yet."]
    lines += [
        "| Task | P | Trials | default | peer | peer's trials | peer | difference | p | verdict |",
        "|---|---:|---:|---:|---|---:|---:|---:|---:|---|",
    ]
    for r in found:
        digits = 2 if r["task"] == "throw" else 3
        ref, peer = r["ref"], r["peer_values"]
        verdict = "behind" if r["diff"] < 0 else "ahead"
        if r["p"] is not None and r["p"] < 0.05:
            verdict = "**lead**" if r["diff"] > 0 else "**behind** (p < 0.05)"
        p = "–" if r["p"] is None else f"{r['p']:.3g}"
        lines.append(
            f"| {r['task']} | {r['levels']} | {r['trials']} "
            f"| {np.mean(ref):.{digits}f} ({len(ref)}) | {r['peer']} | {r['peer_trials']:,} "
            f"| {np.mean(peer):.{digits}f} ({len(peer)}) | {r['diff']:+.{digits}f} | {p} "
            f"| {verdict} |"
        )
    return lines


def _trial_costs(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str, int], np.ndarray]:
    """(task, method, P) → mean wall seconds of trial i (1, 2, ...) over the seeds that ran it."""
    acc: dict[tuple[str, str, int], dict[int, list[float]]] = {}
    for r in rows:
        acc.setdefault((r["task"], r["method"], r["levels"]), {}).setdefault(r["trial"], []).append(
            r["wall_s"]
        )
    return {
        k: np.array([np.mean(v[i]) for i in sorted(v)], dtype=float) for k, v in acc.items() if v
    }


def projected_run_s(per_trial_s: np.ndarray, budget: int, *, grows: bool) -> float:
    """Seconds for one run of ``budget`` trials from a measured per-trial cost curve (trial
    1..n). Measured trials are summed as they are; beyond n, a method whose suggestion cost grows
    with the data (``grows``: BO) follows a + b·i + c·i² with a, b, c ≥ 0, fitted to the medians
    of ten equal slices of the measured curve (robust to a slow spell on a shared machine), never
    below the last slice's median; any other method its median trial cost."""
    from scipy.optimize import nnls

    n = len(per_trial_s)
    done = float(per_trial_s[: min(n, budget)].sum())
    if budget <= n:
        return done
    later = np.arange(n + 1, budget + 1, dtype=float)
    slices = np.array_split(np.arange(n), min(10, n))
    mid = np.array([float(np.mean(s + 1)) for s in slices])
    med = np.array([float(np.median(per_trial_s[s])) for s in slices])
    if grows and n >= 30:
        coef, _ = nnls(np.stack([np.ones_like(mid), mid, mid**2], axis=1), med)
        model = coef[0] + coef[1] * later + coef[2] * later**2
        return done + float(np.maximum(model, med[-1]).sum())
    return done + float(np.median(per_trial_s)) * len(later)


def lpt_makespan_s(run_s: Sequence[float], workers: int) -> float:
    """Wall seconds to run independent runs on ``workers`` cores, longest runs first onto the
    least loaded core (runs are not split)."""
    load = [0.0] * max(1, workers)
    for s in sorted(run_s, reverse=True):
        i = int(np.argmin(load))
        load[i] += s
    return max(load)


def projection_markdown(
    rows: Sequence[dict[str, Any]],
    *,
    seeds: int = 5,
    available: Sequence[str] = SWEEP_METHODS,
    cluster_cores: int = 48,
) -> list[str]:
    """The full grid's projected time on one core and on a ``cluster_cores`` Ray cluster, from the
    per-trial costs measured in ``rows``; (task, method, P) runs with no measurement borrow the
    same method's curve at another P (then another task), and say so."""
    curves = _trial_costs(rows)
    longest: dict[tuple[str, str, int], int] = {}
    for c in grid(available):
        k = (c.task, c.method, c.levels)
        longest[k] = max(longest.get(k, 0), c.trials)
    lines = [
        "## Projected time for the whole grid",
        "",
        f"{seeds} seeds per (task, method, P), each run as long as its largest cell. Per-trial "
        "costs are the runs' own clocks, on the machines that ran them (shared, so on the high "
        "side; a cache's COMPUTED_ELSEWHERE.txt names runs made on other machines); beyond the "
        "measured trials BO follows a non-negative quadratic in the trial number fitted to "
        "its measured cost curve, other methods their median trial cost. *borrowed*: no run "
        "of that P yet, the curve of the same method at another P (or task) stands in.",
        "",
        "| Task | Method | P | Trials | measured trials | basis | s per run (projected) |",
        "|---|---|---:|---:|---:|---|---:|",
    ]
    runs: list[float] = []
    missing = []
    for (task, method, p), budget in sorted(longest.items()):
        curve = curves.get((task, method, p))
        basis = "measured"
        if curve is None:
            near = [v for (t, m, _), v in curves.items() if (t, m) == (task, method)]
            near = near or [v for (_, m, _), v in curves.items() if m == method]
            curve = max(near, key=len) if near else None
            basis = "borrowed"
        if curve is None:
            missing.append(f"{task}/{method}/P={p or '–'}")
            continue
        s = projected_run_s(curve, budget, grows=method.startswith("bo-"))
        runs += [s] * seeds
        shown = min(len(curve), budget) if basis == "measured" else 0
        lines.append(
            f"| {task} | {method} | {p or '–'} | {budget:,} | {shown:,} | {basis} | {s:,.0f} |"
        )
    total = sum(runs)
    lines += [
        "",
        f"- One core: **{total / 3600:,.1f} h** ({len(runs)} runs).",
        f"- A {cluster_cores}-core Ray cluster (one run per core, longest first): "
        f"**{lpt_makespan_s(runs, cluster_cores) / 3600:,.1f} h**, bounded below by the longest "
        f"run ({max(runs, default=0.0) / 3600:,.1f} h).",
    ]
    if missing:
        lines.append(f"- Not projected (no measured run of the method): {', '.join(missing)}.")
    return lines


def _ours(v: list[float], ref: tuple[float, float] | None, chosen: bool, digits: int) -> str:
    if not v:
        return "*unfinished*" if chosen else "*not run*"
    mean, std = float(np.mean(v)), float(np.std(v))
    text = f"**{_fmt(mean, std, digits)}** ({len(v)})"
    if ref is not None and abs(mean - ref[0]) > 2 * ref[1] and math.isfinite(mean):
        text += " ⚠"
    return text
