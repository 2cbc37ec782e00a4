"""REDQ beside BO, CEM and random search at the same trial counts, and beside the paper.

    python benchmarks/redq_side_by_side.py docs/bench/paper/grid/results.csv [--levels 7]

Reads the rows ``handful bench paper`` wrote (every stored run of the grid's cache) and prints,
per task and trial count (250, 500), each method's best objective so far: mean ± std (ddof 0)
over its seeds (n), the paper's number where its tables have one, and Welch's two-sided p of
REDQ against the method. REDQ has no P; the other methods are taken at ``--levels``. Also the
median wall seconds of REDQ's learning episodes (trials after pre-training) per run.
"""

from __future__ import annotations

import argparse
import csv
import statistics

import numpy as np
from scipy.stats import ttest_ind

from app.bench.paper import PAPER_LEVELS, PAPER_REDQ, paper_value
from app.bench.stats import best_at

METHODS = ("redq", "redq-joints", "bo-lei-default", "bo-lei", "bo-ucb", "cem", "random")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("--levels", type=int, default=7, choices=PAPER_LEVELS)
    ap.add_argument("--budgets", type=int, nargs="+", default=[250, 500])
    ap.add_argument("--pretrain", type=int, default=250, help="REDQ's random episodes")
    args = ap.parse_args()
    rows = []
    with open(args.results) as fh:
        for r in csv.DictReader(fh):
            r["levels"], r["seed"] = int(r["levels"]), int(r["seed"])
            r["trial"], r["best_so_far"] = int(r["trial"]), float(r["best_so_far"])
            r["wall_s"] = float(r["wall_s"])
            rows.append(r)
    table = best_at(rows, args.budgets)
    for task in ("throw", "hammer"):
        digits = 2 if task == "throw" else 3
        print(f"\n{task} (REDQ: no P; others: P = {args.levels})\n")
        print(
            "| Method | "
            + " | ".join(f"{n} handful | {n} paper | {n} p vs REDQ" for n in args.budgets)
            + " |"
        )
        print("|---|" + "---:|---:|---:|" * len(args.budgets))
        for m in METHODS:
            cells = []
            for n in args.budgets:
                p = 0 if m.startswith("redq") else args.levels
                v = table.get((task, m, p, n), [])
                redq = table.get((task, "redq", 0, n), [])
                ours = f"{np.mean(v):.{digits}f} ± {np.std(v):.{digits}f} ({len(v)})" if v else "–"
                ref = PAPER_REDQ.get((task, m, n)) or paper_value(task, m, args.levels, n)
                paper = f"{ref[0]:.{digits}f} ± {ref[1]:.{digits}f}" if ref else "–"
                pv = "–"
                if m != "redq" and len(v) >= 2 and len(redq) >= 2:
                    pv = f"{float(ttest_ind(redq, v, equal_var=False).pvalue):.2g}"
                cells += [ours, paper, pv]
            print(f"| {m} | " + " | ".join(cells) + " |")
    print("\nREDQ learning episodes: median wall s per episode, per run")
    for m in ("redq", "redq-joints"):
        for task in ("throw", "hammer"):
            per_run = {}
            for r in rows:
                if (r["method"], r["task"]) == (m, task) and r["trial"] > args.pretrain:
                    per_run.setdefault(r["seed"], []).append(r["wall_s"])
            meds = [statistics.median(v) for _, v in sorted(per_run.items())]
            print(f"{m} {task}: " + ", ".join(f"{x:.2f}" for x in meds))


if __name__ == "__main__":
    main()
