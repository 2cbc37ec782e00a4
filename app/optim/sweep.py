"""The optimiser sweep behind ``handful bench optim``: runs, cache, results.csv, summary, curves.

One *run* is (method, task, P, seed): ``budget`` trials of suggest → decode → rollout → observe.
Each finished trial is appended to ``DIR/runs/<key>.part.csv`` (with θ), and a finished run is
renamed to ``<key>.csv``; an interrupted run resumes by replaying its trials into a fresh
optimiser (suggestions are pure functions of the data, so the result is the same).
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.optim import (
    DEFAULT_METHOD,
    METHODS,
    NEEDS_LEVELS,
    Observation,
    SettingsError,
    make_optimizer,
)

TASKS = ("throw", "hammer", "tip_speed")
# Rough cost per trial, cheapest first: a sweep runs larger P first, cheap methods first within
# a P, so an interrupted sweep still leaves complete rows for them.
_COST_RANK = {
    "random": 0, "cem": 0, "cmaes": 0, "optuna-tpe": 1, "bo-lei": 2, "bo-levels": 3,
    "optuna-gp": 4, "bo-ucb": 5, "bo-lei-default": 6, "bo-turbo": 6, "bo-lei-distinct": 6,
}  # fmt: skip
RESULT_COLUMNS = ("method", "task", "levels", "seed", "trial", "objective", "best_so_far", "wall_s")
_RUN_COLUMNS = ("trial", "objective", "wall_s", "theta")


@dataclass(frozen=True)
class RunSpec:
    """One optimisation run: ``budget`` trials of ``method`` on ``task`` with P = ``levels``."""

    method: str
    task: str
    levels: int
    seed: int
    budget: int
    preset: str = "reference"
    settings: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    label: str | None = None

    @property
    def name(self) -> str:
        """The method's name in outputs: ``label`` (a variant with its own settings) or method."""
        return self.label or self.method

    @property
    def key(self) -> str:
        """File-name stem of this run's cache (the budget is not part of it: longer runs reuse)."""
        return f"{self.task}_P{self.levels}_{self.name}_s{self.seed}_{self.preset}"

    @property
    def with_release(self) -> bool:
        """Throwing has the release step as an extra policy parameter."""
        return self.task == "throw"


def validate(
    *,
    methods: Sequence[str],
    tasks: Sequence[str],
    levels: Sequence[int],
    budgets: Sequence[int],
    seeds: int,
) -> None:
    """Raise SettingsError (one line, naming the culprit) for arguments no sweep can run."""
    for m in methods:
        if m not in METHODS:
            raise SettingsError(f"unknown method {m!r}; choose from {', '.join(METHODS)}")
    for t in tasks:
        if t not in TASKS:
            raise SettingsError(f"unknown task {t!r}; choose from {', '.join(TASKS)}")
    for p in levels:
        if p < 2:
            raise SettingsError(f"levels (P) must be ≥ 2, got {p}")
    for b in budgets:
        if b < 1:
            raise SettingsError(f"budget must be ≥ 1 trial, got {b}")
    if seeds < 1:
        raise SettingsError(f"seeds must be ≥ 1, got {seeds}")
    if not (methods and tasks and levels and budgets):
        raise SettingsError("need at least one method, task, level count and budget")


def make_specs(
    *,
    methods: Sequence[str],
    tasks: Sequence[str],
    levels: Sequence[int],
    budgets: Sequence[int],
    seeds: int,
    preset: str,
) -> list[RunSpec]:
    """All runs of a sweep, each as long as the largest budget."""
    validate(methods=methods, tasks=tasks, levels=levels, budgets=budgets, seeds=seeds)
    n = max(budgets)
    return [
        RunSpec(m, t, p, s, n, preset)
        for t in tasks
        for p in levels
        for m in methods
        for s in range(seeds)
    ]


def objective_fn(task: str, levels: int, preset: str) -> Callable[[np.ndarray], float]:
    """θ (D,) → the task objective of one simulated episode (policy decode → rollout)."""
    from app.policy import Policy
    from app.sim import SimulationDiverged, rollout

    policy = Policy(levels=levels, with_release=(task == "throw"))

    def f(theta: np.ndarray) -> float:
        d = policy.decode(np.clip(theta, 0.0, 1.0))
        try:
            res = rollout(task, d.pressure_schedule_pa, release_step=d.release_step, preset=preset)
        except SimulationDiverged:
            return math.nan
        return float(res.objective)

    return f


def policy_dim(task: str) -> int:
    """D of the paper's policy for ``task`` (H = 10, plus the release step when throwing)."""
    return 10 + int(task == "throw")


def run_dir(out: Path) -> Path:
    """Where per-run caches live."""
    return Path(out) / "runs"


def read_run(path: Path) -> list[dict[str, Any]]:
    """Rows of one run's cache file: trial, objective, wall_s, theta (list)."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            try:
                row = {
                    "trial": int(r["trial"]),
                    "objective": float(r["objective"]),
                    "wall_s": float(r["wall_s"]),
                    "theta": json.loads(r["theta"]),
                }
            except (TypeError, ValueError):
                break  # a line cut short by an interruption: resume from the rows before it
            if row["trial"] != len(rows) + 1:
                break
            rows.append(row)
    return rows


def cached_rows(spec: RunSpec, out: Path) -> list[dict[str, Any]] | None:
    """The finished run's first ``budget`` rows, or None when not cached (long enough)."""
    path = run_dir(out) / f"{spec.key}.csv"
    if not path.exists():
        return None
    rows = read_run(path)
    return rows[: spec.budget] if len(rows) >= spec.budget else None


def stored_rows(spec: RunSpec, out: Path) -> list[dict[str, Any]]:
    """Whatever ``out`` holds of ``spec``: a finished run's rows, else an unfinished run's rows
    so far (possibly none), at most ``budget``."""
    for name in (f"{spec.key}.csv", f"{spec.key}.part.csv"):
        path = run_dir(out) / name
        if path.exists():
            return read_run(path)[: spec.budget]
    return []


def run_one(
    spec: RunSpec,
    out: Path | None = None,
    objective: Callable[[np.ndarray], float] | None = None,
) -> list[dict[str, Any]]:
    """Run (or resume) one optimisation; return its rows (trial, objective, wall_s, theta).

    A diverged simulation counts as the worst value seen so far (0 before any), so the
    optimiser still learns that the point is bad; the row keeps that value.
    """
    import torch

    torch.set_num_threads(1)
    if out is not None:
        done = cached_rows(spec, out)
        if done is not None:
            return done
    f = objective or objective_fn(spec.task, spec.levels, spec.preset)
    settings = dict(spec.settings)
    if (
        spec.method in NEEDS_LEVELS
        or settings.get("space") == "levels"
        or settings.get("initial_design") == "corners"
    ):
        settings.setdefault("levels", spec.levels)
    opt = make_optimizer(spec.method, policy_dim(spec.task), seed=spec.seed, **settings)
    rows: list[dict[str, Any]] = []
    part = None
    if out is not None:
        run_dir(out).mkdir(parents=True, exist_ok=True)
        part = run_dir(out) / f"{spec.key}.part.csv"
        shorter = run_dir(out) / f"{spec.key}.csv"  # a finished run with a smaller budget
        start = part if part.exists() else shorter if shorter.exists() else None
        if start is not None:
            rows = read_run(start)[: spec.budget]
            opt.observe_many(Observation(tuple(r["theta"]), r["objective"]) for r in rows)
            if start == shorter and rows:
                write_part(part, rows)
    fh = None
    try:
        if part is not None:
            fresh = not part.exists() or not rows
            fh = open(part, "w" if fresh else "a", newline="")  # noqa: SIM115
            writer = csv.writer(fh)
            if fresh:
                writer.writerow(_RUN_COLUMNS)
                fh.flush()
        while len(rows) < spec.budget:
            t0 = time.perf_counter()
            theta = opt.suggest(1)[0]
            value = f(theta)
            if not math.isfinite(value):
                value = min((r["objective"] for r in rows), default=0.0)
            opt.observe(theta, value)
            row = {
                "trial": len(rows) + 1,
                "objective": value,
                "wall_s": time.perf_counter() - t0,
                "theta": [float(v) for v in theta],
            }
            rows.append(row)
            if fh is not None:
                writer.writerow(
                    [row["trial"], repr(value), f"{row['wall_s']:.4f}", json.dumps(row["theta"])]
                )
                fh.flush()
    finally:
        if fh is not None:
            fh.close()
    if out is not None:
        write_run(spec, out, rows)
    return rows


def write_part(path: Path, rows: list[dict[str, Any]]) -> None:
    """Start a part file holding ``rows`` (resuming a longer run from a shorter finished one)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(_RUN_COLUMNS)
        for r in rows:
            theta = json.dumps(r["theta"])
            w.writerow([r["trial"], repr(float(r["objective"])), f"{r['wall_s']:.4f}", theta])


def write_run(spec: RunSpec, out: Path, rows: list[dict[str, Any]]) -> None:
    """Store a finished run's rows as ``runs/<key>.csv`` (atomically) and drop its part file."""
    run_dir(out).mkdir(parents=True, exist_ok=True)
    final = run_dir(out) / f"{spec.key}.csv"
    tmp = final.with_suffix(".tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(_RUN_COLUMNS)
        for r in rows:
            w.writerow(
                [
                    r["trial"],
                    repr(float(r["objective"])),
                    f"{r['wall_s']:.4f}",
                    json.dumps(r["theta"]),
                ]
            )
    os.replace(tmp, final)
    (run_dir(out) / f"{spec.key}.part.csv").unlink(missing_ok=True)


def trials_done(spec: RunSpec, out: Path) -> int:
    """How many trials of ``spec`` are on disk (finished or in progress)."""
    for name in (f"{spec.key}.csv", f"{spec.key}.part.csv"):
        path = run_dir(out) / name
        if path.exists():
            try:
                with open(path) as fh:
                    return min(spec.budget, max(0, sum(1 for _ in fh) - 1))
            except OSError:
                return 0
    return 0


# --- outputs ---------------------------------------------------------------------------------
def result_rows(spec: RunSpec, rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """One results.csv row per trial, with the best objective so far."""
    best = -math.inf
    out = []
    for r in rows:
        best = max(best, float(r["objective"]))
        out.append(
            {
                "method": spec.name,
                "task": spec.task,
                "levels": spec.levels,
                "seed": spec.seed,
                "trial": int(r["trial"]),
                "objective": float(r["objective"]),
                "best_so_far": best,
                "wall_s": float(r["wall_s"]),
            }
        )
    return out


def write_results_csv(path: Path, rows: Iterable[dict[str, Any]]) -> None:
    """DIR/results.csv: one row per trial (columns ``RESULT_COLUMNS``)."""
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=RESULT_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    **r,
                    "objective": f"{r['objective']:.6g}",
                    "best_so_far": f"{r['best_so_far']:.6g}",
                    "wall_s": f"{r['wall_s']:.4f}",
                }
            )


def read_results_csv(path: Path) -> list[dict[str, Any]]:
    """Parse DIR/results.csv back into typed rows."""
    with open(path, newline="") as fh:
        return [
            {
                "method": r["method"],
                "task": r["task"],
                "levels": int(r["levels"]),
                "seed": int(r["seed"]),
                "trial": int(r["trial"]),
                "objective": float(r["objective"]),
                "best_so_far": float(r["best_so_far"]),
                "wall_s": float(r["wall_s"]),
            }
            for r in csv.DictReader(fh)
        ]


def best_at(
    rows: Sequence[dict[str, Any]], budgets: Sequence[int]
) -> dict[tuple[str, str, int, int], list[float]]:
    """(task, method, P, budget) → best-so-far after ``budget`` trials, one value per seed."""
    by_run: dict[tuple[str, str, int, int], list[float]] = {}
    for r in rows:
        by_run.setdefault((r["task"], r["method"], r["levels"], r["seed"]), []).append(
            r["best_so_far"]
        )
    out: dict[tuple[str, str, int, int], list[float]] = {}
    for (task, method, p, _seed), curve in sorted(by_run.items()):
        for b in budgets:
            if 1 <= b <= len(curve):
                out.setdefault((task, method, p, b), []).append(curve[b - 1])
    return out


def head_to_head(
    rows: Sequence[dict[str, Any]], budget: int, reference: str
) -> list[dict[str, Any]]:
    """``reference`` vs each other method after ``budget`` trials, per (task, P): means over
    seeds, their difference and Welch's two-sided t-test p-value (None with < 2 seeds a side)."""
    from scipy.stats import ttest_ind

    table = best_at(rows, [budget])
    out = []
    for (task, method, p, _b), peer in sorted(table.items()):
        ref = table.get((task, reference, p, budget))
        if method == reference or not ref:
            continue
        pval = None
        if len(ref) >= 2 and len(peer) >= 2:
            pval = float(ttest_ind(ref, peer, equal_var=False).pvalue)
            pval = 1.0 if math.isnan(pval) else pval  # identical constant samples
        out.append(
            {
                "task": task,
                "levels": p,
                "peer": method,
                "ref_mean": float(np.mean(ref)),
                "ref_n": len(ref),
                "peer_mean": float(np.mean(peer)),
                "peer_n": len(peer),
                "diff": float(np.mean(ref) - np.mean(peer)),
                "p": pval,
            }
        )
    return out


def head_to_head_markdown(rows: Sequence[dict[str, Any]], budget: int, reference: str) -> str:
    """``head_to_head`` as a Markdown table (empty string when ``reference`` has no runs)."""
    pairs = head_to_head(rows, budget, reference)
    if not pairs:
        return ""
    lines = [
        f"## {reference} against each peer after {budget} trials",
        "",
        "Difference of mean best-so-far (positive: "
        f"{reference} ahead) and Welch's two-sided t-test over seeds.",
        "",
        f"| Task | P | Peer | {reference} (n) | peer (n) | difference | p |",
        "|---|---:|---|---:|---:|---:|---:|",
    ]
    for h in pairs:
        p = "–" if h["p"] is None else f"{h['p']:.3f}"
        lines.append(
            f"| {h['task']} | {h['levels']} | {h['peer']} | {h['ref_mean']:.3f} ({h['ref_n']}) "
            f"| {h['peer_mean']:.3f} ({h['peer_n']}) | {h['diff']:+.3f} | {p} |"
        )
    return "\n".join([*lines, ""])


def summary_markdown(
    rows: Sequence[dict[str, Any]],
    budgets: Sequence[int],
    *,
    title: str = "Optimiser sweep",
    reference: str | None = None,
) -> str:
    """The paper's table layout: per task, rows (method, trials), columns P; mean ± std (ddof 0)
    over seeds of the best objective so far. The best mean in each column is bold; a cell with
    fewer seeds than the table's says so (n=k). With ``reference`` (a method), a head-to-head
    table against every peer at the largest budget follows."""
    table = best_at(rows, budgets)
    tasks = sorted({k[0] for k in table}, key=lambda t: TASKS.index(t) if t in TASKS else 99)
    lines = [f"# {title}", ""]
    for task in tasks:
        ps = sorted({k[2] for k in table if k[0] == task})
        methods = [m for m in dict.fromkeys(r["method"] for r in rows if r["task"] == task)]
        seeds = max(len(v) for k, v in table.items() if k[0] == task)
        lines += [
            f"## {task}: best objective so far, mean ± std over {seeds} seeds",
            "",
            "| Method | Trials | " + " | ".join(f"P={p}" for p in ps) + " |",
            "|---|---:|" + "---:|" * len(ps),
        ]
        best_mean = {
            (p, b): max(
                (float(np.mean(v)) for k, v in table.items() if k[0] == task and k[2:] == (p, b)),
                default=math.nan,
            )
            for p in ps
            for b in budgets
        }
        for m in methods:
            for b in budgets:
                cells = []
                for p in ps:
                    v = table.get((task, m, p, b))
                    if not v:
                        cells.append("–")
                        continue
                    mean, std = float(np.mean(v)), float(np.std(v))
                    cell = f"{mean:.3f} ± {std:.3f}"
                    cell = f"**{cell}**" if mean == best_mean[(p, b)] else cell
                    cells.append(cell if len(v) == seeds else f"{cell} (n={len(v)})")
                if any(c != "–" for c in cells):
                    lines.append(f"| {m} | {b} | " + " | ".join(cells) + " |")
        lines.append("")
    if reference is not None:
        lines.append(head_to_head_markdown(rows, max(budgets), reference))
    return "\n".join(lines)


def plot_curves(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """Best-so-far mean curves with ±1 std bands over seeds, one panel per (task, P)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = sorted({(r["task"], r["levels"]) for r in rows})
    methods = list(dict.fromkeys(r["method"] for r in rows))
    ncol = min(2, max(1, len(panels)))
    nrow = math.ceil(len(panels) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6 * ncol, 4 * nrow), squeeze=False)
    colours = plt.get_cmap("tab10")
    for ax, (task, p) in zip(axes.flat, panels, strict=False):
        for i, m in enumerate(methods):
            curves: dict[int, list[float]] = {}
            for r in rows:
                if (r["task"], r["levels"], r["method"]) == (task, p, m):
                    curves.setdefault(r["seed"], []).append(r["best_so_far"])
            if not curves:
                continue
            n = min(len(c) for c in curves.values())
            arr = np.array([c[:n] for c in curves.values()])
            x = np.arange(1, n + 1)
            mean, std = arr.mean(axis=0), arr.std(axis=0)
            # tab10 has 10 colours: past that, the dash pattern tells methods apart
            colour, dashes = colours(i % 10), ("-", "--", ":", "-.")[(i // 10) % 4]
            ax.plot(x, mean, label=f"{m} ({len(curves)})", color=colour, ls=dashes, lw=1.5)
            ax.fill_between(x, mean - std, mean + std, color=colour, alpha=0.15)
        ax.set_title(f"{task}, P = {p}")
        ax.set_xlabel("trial")
        ax.set_ylabel("best objective so far")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels) :]:
        ax.axis("off")
    # One legend per panel: a method may be missing from some panels (e.g. not run at a P).
    for ax in list(axes.flat)[: len(panels)]:
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(
    out: Path,
    specs: Sequence[RunSpec],
    runs: dict[RunSpec, list[dict[str, Any]]],
    budgets: Sequence[int],
) -> list[dict[str, Any]]:
    """Write DIR/results.csv, DIR/summary.md and DIR/curves.png; return the result rows."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [r for s in specs for r in result_rows(s, runs[s])]
    write_results_csv(out / "results.csv", rows)
    preset = specs[0].preset if specs else ""
    (out / "summary.md").write_text(
        summary_markdown(
            rows,
            budgets,
            title=f"Optimiser sweep (sim preset {preset})",
            reference=DEFAULT_METHOD,
        )
        + "\n"
    )
    plot_curves(rows, out / "curves.png")
    return rows


# --- execution ---------------------------------------------------------------------------------
def _run_one_in_worker(spec: RunSpec, out: str | None) -> list[dict[str, Any]]:
    return run_one(spec, Path(out) if out is not None else None)


def run_sweep(
    specs: Sequence[RunSpec],
    out: Path,
    *,
    backend: str = "local",
    address: str | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> dict[RunSpec, list[dict[str, Any]]]:
    """Run every spec not already cached in ``out``; return all runs' rows.

    Backends: ``local`` (a process pool over ``workers`` cores, default all) or ``ray``
    (``ray.init(address)``; a local Ray instance when ``address`` is None). Progress bars count
    runs and trials (trials are read from the run caches as they grow).
    """
    from tqdm import tqdm

    if backend not in ("local", "ray"):
        raise SettingsError(f"backend must be 'local' or 'ray', got {backend!r}")
    out = Path(out)
    run_dir(out).mkdir(parents=True, exist_ok=True)
    results: dict[RunSpec, list[dict[str, Any]]] = {}
    todo = []
    for s in specs:
        rows = cached_rows(s, out)
        if rows is None:
            todo.append(s)
        else:
            results[s] = rows
    todo.sort(key=lambda s: (-s.levels, _COST_RANK.get(s.method, 9)))
    n_workers = max(1, workers or os.cpu_count() or 1)
    total_trials = sum(s.budget for s in specs)
    bar_runs = tqdm(total=len(specs), desc="runs", unit="run", disable=not progress, position=0)
    bar_trials = tqdm(
        total=total_trials, desc="trials", unit="trial", disable=not progress, position=1
    )
    bar_runs.update(len(results))

    def refresh() -> None:
        done = sum(s.budget if s in results else trials_done(s, out) for s in specs)
        bar_trials.update(done - bar_trials.n)

    refresh()
    try:
        if todo and backend == "local" and n_workers == 1:
            for s in todo:
                results[s] = run_one(s, out)
                bar_runs.update(1)
                refresh()
        elif todo and backend == "local":
            from concurrent.futures import FIRST_COMPLETED, wait

            from app.procs import process_pool

            with process_pool(min(n_workers, len(todo))) as ex:
                futs = {ex.submit(_run_one_in_worker, s, str(out)): s for s in todo}
                pending = set(futs)
                while pending:
                    finished, pending = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
                    for fut in finished:
                        results[futs[fut]] = fut.result()
                        bar_runs.update(1)
                    refresh()
        elif todo:
            import ray

            started = not ray.is_initialized()
            if started:
                if address:
                    ray.init(address=address, log_to_driver=False)
                else:
                    ray.init(num_cpus=n_workers, log_to_driver=False, include_dashboard=False)
            try:
                remote = ray.remote(num_cpus=1)(_run_one_in_worker)
                refs = {remote.remote(s, str(out.resolve())): s for s in todo}
                pending_refs = list(refs)
                while pending_refs:
                    ready, pending_refs = ray.wait(pending_refs, num_returns=1, timeout=1.0)
                    for ref in ready:
                        s = refs[ref]
                        results[s] = ray.get(ref)
                        # On a cluster the workers' disks are not ours: cache here too.
                        if cached_rows(s, out) is None:
                            write_run(s, out, results[s])
                        bar_runs.update(1)
                    refresh()
            finally:
                if started:
                    ray.shutdown()
    finally:
        bar_trials.close()
        bar_runs.close()
    return results
