"""The optimiser sweep's ranking in the paper-matching settings, from both caches' results.

    python benchmarks/sweep_ranking.py --grid docs/bench/paper/grid/results.csv \
        --sweep docs/bench/optim/paper_sweep/results.csv --levels 2 5 --budget 100
    python benchmarks/sweep_ranking.py --sweep docs/bench/optim/paper_sweep/results.csv \
        --before docs/bench/paper/grid/results.csv docs/bench/optim/paper_sweep/fast-r1/results.csv

The paper grid (``handful bench paper``) holds random search, the paper's CEM (σ₀ = 1/√12),
BO-LEI, BO-UCB and handful's default (BO fits ``warm``); the sweep's own cache (``handful bench
optim``) holds the other methods (CEM with handful's σ₀ = 1, CMA-ES, Optuna, bo-levels, ...;
the paper's full GP refits). Both must come from one preset, command hold and scoring rule;
the script refuses a mix. ``--grid`` may be left out where the sweep holds every method,
handful's default included (the sweep in `fast` revision 2). Per task and P it prints every
method's best objective after ``--budget`` trials, mean ± std (ddof 0) over the seeds that
reached it (n), best first, Welch's two-sided p of handful's default against each, and the
paper's number where the paper has the method (random search, its CEM, BO-LEI, BO-UCB).
``--before`` sets an earlier ranking beside it (its own settings, e.g. the same methods in
`fast-r1`): each method's value then and its rank then.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from app.bench.paper import paper_value
from app.bench.report import read_results_csv
from app.bench.stats import best_at, welch_p
from app.optim import DEFAULT_METHOD

#: the name each cache's CEM gets in the ranking (they differ in their initial spread)
CEM_NAMES = {"grid": "cem (paper σ₀)", "sweep": "cem (σ₀ = 1)"}
#: the paper's name of a ranked method, where it differs (only the paper's own CEM has a row)
PAPER_NAMES = {CEM_NAMES["grid"]: "cem"}


def load(path: Path, source: str) -> list[dict]:
    """``results.csv`` rows, with the cache's CEM renamed (``CEM_NAMES``)."""
    rows = read_results_csv(path)
    for r in rows:
        if r["method"] == "cem":
            r["method"] = CEM_NAMES[source]
    return rows


def settings_of(rows: list[dict]) -> tuple[str, str, str]:
    """The one (preset, command hold, scoring rule) of ``rows``; exits on a mix."""
    settings = {(r["preset"], r["command_hold"], r["objective_rule"]) for r in rows}
    if len(settings) != 1:
        raise SystemExit(f"the caches mix settings (preset, hold, rule): {sorted(settings)}")
    return settings.pop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--grid", type=Path, default=None, help="the paper grid's results.csv (optional)"
    )
    ap.add_argument("--sweep", type=Path, required=True, help="the sweep's results.csv")
    ap.add_argument(
        "--before",
        type=Path,
        nargs="+",
        default=None,
        help="results.csv files of an earlier ranking (grid first, if any) to set beside it",
    )
    ap.add_argument("--levels", type=int, nargs="+", default=[2, 5])
    ap.add_argument("--budget", type=int, default=100)
    args = ap.parse_args()
    rows = (load(args.grid, "grid") if args.grid else []) + load(args.sweep, "sweep")
    preset, hold, rule = settings_of(rows)
    table = best_at(rows, [args.budget])
    before: dict = {}
    if args.before:
        sources = ["grid", "sweep"] if len(args.before) == 2 else ["sweep"]
        old = [r for path, src in zip(args.before, sources, strict=True) for r in load(path, src)]
        old_preset = settings_of(old)[0]
        before = best_at(old, [args.budget])
    print(f"preset {preset}, command hold {hold}, scoring rule {rule}; best after {args.budget}")
    for task in ("throw", "hammer"):
        digits = 2 if task == "throw" else 3
        for p in args.levels:
            cells = {m: v for (t, m, lv, _b), v in table.items() if (t, lv) == (task, p)}
            if not cells:
                continue
            ref = cells.get(DEFAULT_METHOD, [])
            old_cells = {m: v for (t, m, lv, _b), v in before.items() if (t, lv) == (task, p)}
            old_rank = {
                m: i
                for i, (m, _v) in enumerate(
                    sorted(old_cells.items(), key=lambda kv: -float(np.mean(kv[1]))), start=1
                )
            }
            extra = f" {old_preset}: best after {args.budget} | rank then |" if before else ""
            print(f"\n{task}, P = {p}\n")
            print(
                f"| method | best after {args.budget} | n | p vs {DEFAULT_METHOD} | paper |{extra}"
            )
            print("|---|---:|---:|---:|---:|" + ("---:|---:|" if before else ""))
            ranked = sorted(cells.items(), key=lambda kv: -float(np.mean(kv[1])))
            for m, v in ranked:
                pv = welch_p(ref, v) if m != DEFAULT_METHOD else None
                ref_paper = paper_value(task, PAPER_NAMES.get(m, m), p, args.budget)
                line = (
                    f"| {m} | {np.mean(v):.{digits}f} ± {np.std(v):.{digits}f} | {len(v)} | "
                    f"{'–' if pv is None else f'{pv:.2g}'} | "
                    + (
                        f"{ref_paper[0]:.{digits}f} ± {ref_paper[1]:.{digits}f} |"
                        if ref_paper
                        else "– |"
                    )
                )
                if before:
                    o = old_cells.get(m)
                    line += (
                        f" {np.mean(o):.{digits}f} ± {np.std(o):.{digits}f} | {old_rank[m]} |"
                        if o
                        else " – | – |"
                    )
                print(line)


if __name__ == "__main__":
    main()
