"""A sweep's outputs: DIR/results.csv, the Markdown summary (the paper's table layout and a
head-to-head table) and the best-so-far curves."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.bench.specs import RunSpec
from app.bench.stats import best_at, head_to_head, result_rows
from app.optim import DEFAULT_METHOD
from app.policy import TASKS

RESULT_COLUMNS = (
    "method", "task", "levels", "seed", "trial", "objective", "best_so_far", "wall_s",
    "preset", "command_hold", "objective_rule",
)  # fmt: skip


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
                # older files: the simulator settings of their time
                "preset": r.get("preset") or "",
                "command_hold": r.get("command_hold") or "zero",
                "objective_rule": r.get("objective_rule") or "paper",
            }
            for r in csv.DictReader(fh)
        ]


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
    sims = sorted({(s.preset, s.command_hold, s.objective_rule) for s in specs})
    where = "; ".join(f"sim preset {p}, command hold {h}, objective {o}" for p, h, o in sims)
    (out / "summary.md").write_text(
        summary_markdown(
            rows,
            budgets,
            title=f"Optimiser sweep ({where})",
            reference=DEFAULT_METHOD,
        )
        + "\n"
    )
    plot_curves(rows, out / "curves.png")
    return rows
