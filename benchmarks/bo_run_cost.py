"""What a whole 500-trial BO-LEI run costs with handful's faster GP fits (``--bo-fit warm``,
``fast``) against the paper's full refit, measured in one process on one core, same data.

    python benchmarks/bo_run_cost.py --cache docs/bench/paper/grid --task throw --seed 0 \
        --trials 500 --fits warm fast --full-every 25

A stored ``bo-lei`` run (P = 7, the paper's preset, hold and rule, ``--bo-fit warm``, in
``--cache``) is replayed trial by trial through optimisers built exactly as ``handful bench
paper`` builds them (``RunSpec.optimizer_spec``): one per ``--fits`` name, and the paper's
``full``. All observe every stored trial. Before each trial every ``--fits`` optimiser suggests
(their anchors depend on the order, so every trial is timed); the full one suggests every
``--full-every``-th trial (a full refit depends on the data alone) and the trials between are
interpolated linearly. Each suggestion is timed in CPU seconds of this process
(``time.process_time``, torch on one thread, the optimisers interleaved), so the other core's
load moves them alike. An episode's cost is the mean CPU time of ``--episodes`` of the run's
own θ through the simulator. Whole run = Σ suggestions + trials × episode, as a run's own
clock counts it (observing and writing the row are negligible). Writes a Markdown table
(stdout, and ``--md``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from bo_fit_noloss import bo_lei_spec as spec

from app.bench.cache import stored_rows
from app.bench.runner import objective_fn
from app.optim import build_optimizer
from app.policy import PAPER_COMMAND_HOLD, PAPER_OBJECTIVE_RULE, PAPER_PRESET


def cpu(fn) -> float:  # type: ignore[no-untyped-def]
    """CPU seconds of this process that ``fn()`` takes."""
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, default=Path("docs/bench/paper/grid"))
    ap.add_argument("--task", default="throw", choices=("throw", "hammer"))
    ap.add_argument("--levels", type=int, default=7)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trials", type=int, default=500)
    ap.add_argument("--fits", nargs="+", default=["warm", "fast"], choices=["warm", "fast"])
    ap.add_argument("--full-every", type=int, default=25)
    ap.add_argument("--episodes", type=int, default=25)
    ap.add_argument("--md", type=Path, help="also write the table here")
    a = ap.parse_args()
    torch.set_num_threads(1)
    rows = stored_rows(spec(a.task, a.levels, a.seed, "warm"), a.cache)
    if len(rows) < a.trials:
        sys.exit(f"the stored warm run has {len(rows)} trials, fewer than --trials {a.trials}")
    rows = rows[: a.trials]
    theta = np.array([r["theta"] for r in rows])
    y = [float(r["objective"]) for r in rows]
    opts = {f: build_optimizer(spec(a.task, a.levels, a.seed, f).optimizer_spec()) for f in a.fits}
    full = build_optimizer(spec(a.task, a.levels, a.seed, "full").optimizer_spec())
    sampled = sorted({*range(0, a.trials, a.full_every), a.trials - 1})
    t = {f: np.zeros(a.trials) for f in a.fits}
    t_full: dict[int, float] = {}
    start = time.monotonic()
    for n in range(a.trials):  # n observations so far; trial n + 1 is suggested
        for f, opt in opts.items():
            t[f][n] = cpu(lambda opt=opt: opt.suggest(1))
        if n in sampled:
            t_full[n] = cpu(lambda: full.suggest(1))
        for opt in (*opts.values(), full):
            opt.observe(theta[n], y[n])
        if (n + 1) % 25 == 0:
            el = time.monotonic() - start
            per = sum(t[f][n - 24 : n + 1].sum() for f in a.fits) / 25
            per += t_full[max(t_full)] / a.full_every
            print(
                f"  {n + 1}/{a.trials} trials, {el:.0f} s, ETA ≈ {per * (a.trials - n - 1):.0f} s",
                file=sys.stderr,
                flush=True,
            )
    ks = np.array(sorted(t_full))
    full_all = np.interp(np.arange(a.trials), ks, [t_full[k] for k in ks])
    obj = objective_fn(a.task, a.levels, PAPER_PRESET, PAPER_COMMAND_HOLD, PAPER_OBJECTIVE_RULE)
    picks = np.linspace(0, a.trials - 1, a.episodes).astype(int)
    episode = float(np.mean([cpu(lambda i=i: obj(theta[i])) for i in picks]))
    eps = a.trials * episode
    whole = {f: float(t[f].sum()) + eps for f in a.fits}
    whole_full = float(full_all.sum()) + eps
    names = " | ".join(f"`{f}` suggestion" for f in a.fits)
    lines = [
        f"BO-LEI, {a.task}, P = {a.levels}, seed {a.seed}: the stored warm run's first "
        f"{a.trials} trials replayed (simulator preset `{PAPER_PRESET}`, command hold "
        f"`{PAPER_COMMAND_HOLD}`, scoring rule `{PAPER_OBJECTIVE_RULE}`); CPU seconds, one "
        "core, one process.",
        "",
        f"| N (observed) | {names} | `full` suggestion | "
        + " | ".join(f"`{f}` ÷ full" for f in a.fits)
        + " |",
        "|---:|" + "---:|" * (2 * len(a.fits) + 1),
    ]
    for k in ks:
        if k % 50 and k != ks[-1]:
            continue
        cells = " | ".join(f"{t[f][k]:.3f}" for f in a.fits)
        ratios = " | ".join(f"{t[f][k] / t_full[k]:.3f}" for f in a.fits)
        lines.append(f"| {k} | {cells} | {t_full[k]:.3f} | {ratios} |")
    lines += [
        "",
        "| whole run | suggestions (s) | episodes (s) | total (s) | full ÷ this |",
        "|---|---:|---:|---:|---:|",
        *(
            f"| `{f}` | {t[f].sum():.0f} | {eps:.0f} | {whole[f]:.0f} | "
            f"**{whole_full / whole[f]:.2f}×** |"
            for f in a.fits
        ),
        f"| `full` (the paper's) | {full_all.sum():.0f} | {eps:.0f} | {whole_full:.0f} | 1.00× |",
        "",
        f"Episode {episode * 1e3:.0f} ms CPU (mean of {a.episodes} of the run's θ); full "
        f"suggestions measured at {len(ks)} sizes, every {a.full_every}, interpolated between.",
    ]
    text = "\n".join(lines)
    print(text)
    if a.md:
        a.md.write_text(text + "\n")


if __name__ == "__main__":
    main()
