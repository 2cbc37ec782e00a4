"""Choose the paper-matching preset: the published simulator's random-search anchor through handful.

The anchor (../shared/fidelity/random_anchor.json, trimmed copy in
tests/sim/data/random_anchor_throw.json) holds random θ decoded by handful's own Policy and run
through the published simulator, with their J under each command mode and scoring rule. This
runs the same θ through handful in one (physics preset, command hold) per call, scores every
episode under both rules, and prints, per (P, rule), best-after-100 per seed beside the published
simulator's ramped/published-rule numbers and the paper's row, plus the per-θ agreement.

    nice -n 10 python benchmarks/paper_anchor.py --preset reference --command-hold linear \
        --levels 7 2 --seeds 2024 --workers 2 --out docs/bench/paper/anchor_reference_linear.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from app.policy import Policy
from app.sim import rollout_batch

ANCHOR = Path(__file__).resolve().parents[1] / "tests" / "sim" / "data" / "random_anchor_throw.json"
PAPER_RANDOM_100 = {2: (27.435, 1.349), 5: (22.125, 1.763), 7: (19.167, 1.795), 10: (20.614, 3.245)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="reference")
    ap.add_argument("--command-hold", default="linear")
    ap.add_argument("--levels", type=int, nargs="+", default=[7, 2])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2024])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    anchor = json.loads(ANCHOR.read_text())
    mode = {"zero": "zoh", "linear": "foh"}[args.command_hold]
    report: dict = {"preset": args.preset, "command_hold": args.command_hold, "rows": []}
    for levels in args.levels:
        policy = Policy(levels=levels, with_release=True, p_max_pa=275800.0)
        for seed in args.seeds:
            recs = [r for r in anchor["records"] if r["P"] == levels and r["seed"] == seed]
            recs.sort(key=lambda r: r["trial"])
            decoded = [policy.decode(np.asarray(r["theta"])) for r in recs]
            t0 = time.perf_counter()
            results = rollout_batch(
                "throw",
                [d.pressure_schedule_pa for d in decoded],
                release_steps=[d.release_step for d in decoded],
                preset=args.preset,
                command_hold=args.command_hold,
                n_workers=args.workers,
            )
            wall = time.perf_counter() - t0
            pub = np.array([r[f"J_{mode}_published"] for r in recs])
            row = {"P": levels, "seed": seed, "n": len(recs), "wall_s": round(wall, 1)}
            for rule in ("paper", "published"):
                mine = np.array([res.objective_by_rule[rule] for res in results])
                row[rule] = {
                    "best100": round(float(mine.max()), 3),
                    "median": round(float(np.median(mine)), 3),
                    "corr_with_published_sim": round(float(np.corrcoef(mine, pub)[0, 1]), 3),
                    "median_abs_rel_diff": round(float(np.median(np.abs(mine / pub - 1))), 3),
                }
            row["published_sim"] = {
                "best100": round(float(pub.max()), 3),
                "median": round(float(np.median(pub)), 3),
            }
            lost = [res.cube_lost_before_release for res in results]
            row["lost_share"] = round(sum(bool(x) for x in lost) / len(lost), 3)
            row["paper_random_100"] = PAPER_RANDOM_100.get(levels)
            report["rows"].append(row)
            print(json.dumps(row), flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
