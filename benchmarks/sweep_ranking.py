"""The optimiser sweep's ranking in the paper-matching settings, from both caches' results.

    python benchmarks/sweep_ranking.py --grid docs/bench/paper/grid/results.csv \
        --sweep docs/bench/optim/paper_sweep/results.csv --levels 2 5 --budget 100
    python benchmarks/sweep_ranking.py --sweep docs/bench/optim/paper_sweep/results.csv

The paper grid (``handful bench paper``) holds random search, the paper's CEM (σ₀ = 1/√12),
BO-LEI, BO-UCB and handful's default (BO fits ``warm``); the sweep's own cache (``handful bench
optim``) holds the other methods (CEM with handful's σ₀ = 1, CMA-ES, Optuna, bo-levels, ...;
the paper's full GP refits). Both must come from one preset, command hold and scoring rule;
the script refuses a mix. ``--grid`` may be left out where the sweep holds every method,
handful's default included (the sweep in `fast` revision 2). Per task and P it prints every
method's best objective after ``--budget`` trials, mean ± std (ddof 0) over the seeds that
reached it (n), best first, and Welch's two-sided p of handful's default against each.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from app.bench.report import read_results_csv
from app.bench.stats import best_at, welch_p
from app.optim import DEFAULT_METHOD

#: the name each cache's CEM gets in the ranking (they differ in their initial spread)
CEM_NAMES = {"grid": "cem (paper σ₀)", "sweep": "cem (σ₀ = 1)"}


def load(path: Path, source: str) -> list[dict]:
    """``results.csv`` rows, with the cache's CEM renamed (``CEM_NAMES``)."""
    rows = read_results_csv(path)
    for r in rows:
        if r["method"] == "cem":
            r["method"] = CEM_NAMES[source]
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--grid", type=Path, default=None, help="the paper grid's results.csv (optional)"
    )
    ap.add_argument("--sweep", type=Path, required=True, help="the sweep's results.csv")
    ap.add_argument("--levels", type=int, nargs="+", default=[2, 5])
    ap.add_argument("--budget", type=int, default=100)
    args = ap.parse_args()
    rows = (load(args.grid, "grid") if args.grid else []) + load(args.sweep, "sweep")
    settings = {(r["preset"], r["command_hold"], r["objective_rule"]) for r in rows}
    if len(settings) != 1:
        raise SystemExit(f"the two caches mix settings (preset, hold, rule): {sorted(settings)}")
    preset, hold, rule = settings.pop()
    table = best_at(rows, [args.budget])
    print(f"preset {preset}, command hold {hold}, scoring rule {rule}; best after {args.budget}")
    for task in ("throw", "hammer"):
        digits = 2 if task == "throw" else 3
        for p in args.levels:
            cells = {m: v for (t, m, lv, _b), v in table.items() if (t, lv) == (task, p)}
            if not cells:
                continue
            ref = cells.get(DEFAULT_METHOD, [])
            print(f"\n{task}, P = {p}\n")
            print(f"| method | best after {args.budget} | n | p vs {DEFAULT_METHOD} |")
            print("|---|---:|---:|---:|")
            for m, v in sorted(cells.items(), key=lambda kv: -float(np.mean(kv[1]))):
                pv = welch_p(ref, v) if m != DEFAULT_METHOD else None
                print(
                    f"| {m} | {np.mean(v):.{digits}f} ± {np.std(v):.{digits}f} | {len(v)} | "
                    f"{'–' if pv is None else f'{pv:.2g}'} |"
                )


if __name__ == "__main__":
    main()
