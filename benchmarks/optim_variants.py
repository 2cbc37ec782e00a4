"""Compare BO variants (handful's candidates) with the peers on the simulated tasks.

    python benchmarks/optim_variants.py --out bench_out/variants --tasks throw,hammer \\
        --levels 5 --seeds 4 --budget 100 --preset fast --workers 16

Writes the same results.csv / summary.md / curves.png as ``handful bench optim``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app import bench

# label → (method, settings)
VARIANTS: dict[str, tuple[str, dict]] = {
    "lv-default-corners": ("bo-levels", {}),
    "lv-default-sobol": ("bo-levels", {"initial_design": "sobol"}),
    "lv-paper-corners": ("bo-levels", {"model_preset": "paper", "fit_maxiter": None}),
    "lv-default-corners-ucb": ("bo-levels", {"acquisition": "ucb"}),
    "theta-paper-corners": ("bo-lei", {"initial_design": "corners"}),
}
PEERS = ("bo-lei", "cem", "random", "optuna-tpe", "optuna-gp", "cmaes")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("bench_out/variants"))
    ap.add_argument("--tasks", default="throw,hammer")
    ap.add_argument("--levels", default="5")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--peers", default=",".join(PEERS))
    a = ap.parse_args()
    specs = []
    for task in a.tasks.split(","):
        for p in (int(v) for v in a.levels.split(",")):
            for seed in range(a.seeds):
                for label in filter(None, a.variants.split(",")):
                    method, settings = VARIANTS[label]
                    specs.append(
                        bench.RunSpec(
                            method, task, p, seed, a.budget, a.preset, dict(settings), label
                        )
                    )
                for m in filter(None, a.peers.split(",")):
                    specs.append(bench.RunSpec(m, task, p, seed, a.budget, a.preset))
    # Slow (BO) runs first so the pool's tail is short.
    specs.sort(key=lambda s: s.method.startswith("bo") or s.method == "optuna-gp", reverse=True)
    runs = bench.run_sweep(specs, a.out, workers=a.workers, progress=False)
    bench.write_outputs(a.out, specs, runs, [a.budget // 4, a.budget // 2, a.budget])
    print((a.out / "summary.md").read_text())


if __name__ == "__main__":
    main()
