"""The next BO suggestion with warm-started GP fits vs raw BoTorch from scratch, same data.

    python benchmarks/optim_warm.py --sizes 100 500 --dim 11 --steps 50 --raw-every 10

For each N0 in ``--sizes``: a live ``bo-lei`` optimiser with ``fit_mode="warm"`` that has
already answered at N0 − 1 observations (so it holds its last anchor fit, as in a sweep) then
observes one trial at a time for ``--steps`` steps and suggests after each. Every
``--raw-every``-th step, raw BoTorch fits the paper's GP from scratch and maximises LogEI with
the same settings on the same data (what ``fit_mode="full"`` does each step). Reported: the
median warm suggestion, the mean over all steps (it includes the full fits at anchors, so it is
the amortised cost), the worst step, the median raw suggestion, and their ratios. One core
(``torch.set_num_threads(1)``), both sides in the same run, interleaved.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import torch
from optim_latency import objective, raw_suggest

from app.optim import Observation, make_optimizer
from app.optim.bo import anchor_size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 500])
    ap.add_argument("--dim", type=int, default=11)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--raw-every", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    print(f"torch threads: {torch.get_num_threads()}; warm: refit_every 10, refit_fraction 0.1")
    print(
        "| N (steps) | full fits in steps | warm median (s) | warm mean (s) | warm worst (s) "
        "| raw from scratch median (s) | warm median / raw | warm mean / raw |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    results = []
    for n0 in a.sizes:
        rng = np.random.default_rng(n0)
        x = rng.random((n0 + a.steps, a.dim))
        y = objective(x) + 0.05 * rng.standard_normal(len(x))
        opt = make_optimizer(
            "bo-lei", a.dim, seed=a.seed, num_restarts=10, raw_samples=512, fit_mode="warm"
        )
        head = zip(x[: n0 - 1], y[: n0 - 1], strict=True)
        opt.observe_many(Observation(tuple(xi), float(yi)) for xi, yi in head)
        opt.model()  # the live optimiser's state before the measured steps (anchor fitted)
        t_warm, t_raw = [], []
        for k in range(a.steps):
            n = n0 + k
            opt.observe(x[n - 1], float(y[n - 1]))
            t0 = time.perf_counter()
            opt.suggest(1)
            t_warm.append(time.perf_counter() - t0)
            if k % a.raw_every == 0:
                t0 = time.perf_counter()
                raw_suggest(x[:n], y[:n], seed=a.seed)
                t_raw.append(time.perf_counter() - t0)
        anchors = sorted({anchor_size(n0 + k, 10, 0.1) for k in range(a.steps)} - {n0 - 1})
        n_full = sum(1 for v in anchors if n0 <= v < n0 + a.steps)
        w_med, w_mean, w_max = statistics.median(t_warm), statistics.mean(t_warm), max(t_warm)
        r_med = statistics.median(t_raw)
        results.append({"n0": n0, "warm_s": t_warm, "raw_s": t_raw, "full_fits": n_full})
        print(
            f"| {n0}..{n0 + a.steps - 1} | {n_full} | {w_med:.3f} | {w_mean:.3f} | {w_max:.2f} "
            f"| {r_med:.3f} | {w_med / r_med:.3f} | {w_mean / r_med:.3f} |",
            flush=True,
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
