"""Does the warm GP fit lose sample efficiency? BO-LEI with ``--bo-fit warm`` (the committed
grid's BO runs) against the paper's full refit after every trial, on the runs ``handful bench
paper`` cached for both, and what each whole run cost.

    handful bench paper --preset fast-r1 --bo-fit warm --cells "method=bo-lei P=7" \
        --trials 100,500 --out docs/bench/paper/grid
    handful bench paper --preset fast-r1 --bo-fit full --cells "method=bo-lei P=7" \
        --trials 100,500 --out docs/bench/paper/grid_full
    python benchmarks/bo_fit_noloss.py --preset fast-r1 --warm docs/bench/paper/grid \
        --full docs/bench/paper/grid_full --levels 7 --budgets 100 500
    # the fast mode (``--bo-fit fast``, its runs in their own folder) the same way:
    python benchmarks/bo_fit_noloss.py --preset fast-r1 --fit fast \
        --warm docs/bench/paper/grid_fast --full docs/bench/paper/grid_full --levels 7 \
        --budgets 100 500

Writes a Markdown table (stdout, and ``--md``): best-so-far after each budget, mean ± std over
the seeds both sides reached, Welch's two-sided t-test p-value, and the mean wall seconds of a
whole run of that length (suggestion + episode, each run's own clock) with their ratio. Runs
still in progress count for the budgets they have reached.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from scipy.stats import ttest_ind

from app.bench.cache import stored_rows
from app.bench.paper import BO_FITS
from app.bench.specs import RunSpec
from app.policy import PAPER_COMMAND_HOLD, PAPER_OBJECTIVE_RULE, PAPER_PRESET


def bo_lei_spec(task: str, levels: int, seed: int, fit: str, preset: str = PAPER_PRESET) -> RunSpec:
    """The grid's BO-LEI run with ``--bo-fit fit`` (the paper's settings otherwise)."""
    return RunSpec(
        "bo-lei",
        task,
        levels,
        seed,
        10_000,
        preset,
        settings=dict(BO_FITS[fit]),
        command_hold=PAPER_COMMAND_HOLD,
        objective_rule=PAPER_OBJECTIVE_RULE,
    )


def runs(
    out: Path, task: str, levels: int, fit: str, seeds: int, preset: str = PAPER_PRESET
) -> list[list[dict]]:
    """Each seed's stored rows (finished or in progress) of bo-lei with ``--bo-fit fit``."""
    got = []
    for s in range(seeds):
        spec = bo_lei_spec(task, levels, s, fit, preset)
        got.append(stored_rows(spec, out))
    return got


def at(rows_per_seed: list[list[dict]], budget: int) -> tuple[list[float], list[float]]:
    """Best-so-far after ``budget`` trials and the run's wall seconds to get there, per seed."""
    best, cost = [], []
    for rows in rows_per_seed:
        if len(rows) >= budget:
            best.append(max(r["objective"] for r in rows[:budget]))
            cost.append(sum(r["wall_s"] for r in rows[:budget]))
    return best, cost


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--warm", type=Path, required=True, help="cache folder of the warm runs")
    ap.add_argument(
        "--fit",
        default="warm",
        choices=[f for f in BO_FITS if f != "full"],
        help="the --bo-fit of the runs in --warm (warm or fast)",
    )
    ap.add_argument("--full", type=Path, required=True, help="cache folder of the full runs")
    ap.add_argument("--levels", type=int, default=7)
    ap.add_argument(
        "--preset", default=PAPER_PRESET, help="the runs' simulator preset (committed: fast-r1)"
    )
    ap.add_argument("--budgets", type=int, nargs="+", default=[100, 500])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--md", type=Path, help="also write the table here")
    a = ap.parse_args()
    lines = [
        f"BO-LEI, P = {a.levels}: `--bo-fit {a.fit}` vs `full` (simulator preset `{a.preset}`, "
        f"command hold `{PAPER_COMMAND_HOLD}`, scoring rule `{PAPER_OBJECTIVE_RULE}`). "
        "Best so far: mean ± std (ddof 1) over seeds (n); p: Welch's two-sided t-test; "
        "cost: mean wall seconds of a whole run of that length.",
        "",
        f"| Task | Trials | {a.fit} | full | Welch p | {a.fit} s/run | full s/run "
        f"| full ÷ {a.fit} |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for task in ("throw", "hammer"):
        w_runs = runs(a.warm, task, a.levels, a.fit, a.seeds, a.preset)
        f_runs = runs(a.full, task, a.levels, "full", a.seeds, a.preset)
        for b in a.budgets:
            (wb, wc), (fb, fc) = at(w_runs, b), at(f_runs, b)
            if not wb and not fb:
                lines.append(f"| {task} | {b} | *not run* | *not run* | | | | |")
                continue

            def fmt(v: list[float]) -> str:
                if not v:
                    return "*not run*"
                sd = float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
                return f"{np.mean(v):.3f} ± {sd:.3f} ({len(v)})"

            p = ""
            if len(wb) >= 2 and len(fb) >= 2:
                pv = float(ttest_ind(wb, fb, equal_var=False).pvalue)
                p = "1.000" if math.isnan(pv) else f"{pv:.3f}"
            ratio = f"{np.mean(fc) / np.mean(wc):.2f}×" if wc and fc else ""
            lines.append(
                f"| {task} | {b} | {fmt(wb)} | {fmt(fb)} | {p} "
                f"| {f'{np.mean(wc):.0f}' if wc else '–'} "
                f"| {f'{np.mean(fc):.0f}' if fc else '–'} | {ratio} |"
            )
    text = "\n".join(lines) + "\n"
    print(text)
    if a.md:
        a.md.write_text(text)


if __name__ == "__main__":
    main()
