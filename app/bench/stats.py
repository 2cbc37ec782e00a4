"""Statistics over a sweep's result rows: best-so-far per budget and head-to-head t-tests."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from app.bench.specs import RunSpec


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
                "preset": spec.preset,
                "command_hold": spec.command_hold,
                "objective_rule": spec.objective_rule,
            }
        )
    return out


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


def welch_p(a: Sequence[float], b: Sequence[float]) -> float | None:
    """Welch's two-sided t-test p of two samples; None with fewer than 2 values a side, 1.0
    for identical constant samples."""
    from scipy.stats import ttest_ind

    if len(a) < 2 or len(b) < 2:
        return None
    pval = float(ttest_ind(a, b, equal_var=False).pvalue)
    return 1.0 if math.isnan(pval) else pval


def head_to_head(
    rows: Sequence[dict[str, Any]], budget: int, reference: str
) -> list[dict[str, Any]]:
    """``reference`` vs each other method after ``budget`` trials, per (task, P): means over
    seeds, their difference and Welch's two-sided t-test p-value (None with < 2 seeds a side)."""
    table = best_at(rows, [budget])
    out = []
    for (task, method, p, _b), peer in sorted(table.items()):
        ref = table.get((task, reference, p, budget))
        if method == reference or not ref:
            continue
        pval = welch_p(ref, peer)
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
