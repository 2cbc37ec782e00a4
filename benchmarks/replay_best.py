"""Replay each cached run's best θ in another preset: what the optimisers found, elsewhere.

Takes every finished run of a sweep folder for one task in one (preset, command hold, scoring
rule), picks the run's best θ (what an optimiser would hand over) and runs it again in
``--against`` with the same hold and rule. Printed per (P, method): the objective in each
preset (mean ± std over the seeds' best θ), and for throws how many of them the other preset's
grasp loses before the release step and the cube's distance.

Two uses (docs/bench/paper.md (f) and (e⁵)):

* Does `fast`'s weld flatter the optimisers? Its best throws in the reference preset (friction
  grasp), beside the published simulator's J for the same θ (``--published``):

      nice -n 10 python benchmarks/replay_best.py --sweep docs/bench/optim/paper_sweep \
          --preset fast --against reference --levels 2 5 \
          --published tests/sim/data/published_optimised_throws.json \
          --json docs/bench/paper/weld_check_fast_linear.json

* What did revision 1 of `fast` let the hammer do? Its best hammer θ in revision 2:

      nice -n 10 python benchmarks/replay_best.py --sweep docs/bench/optim/paper_sweep \
          --task hammer --preset fast-r1 --against fast --levels 2 5
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from app.bench.cache import read_run
from app.bench.runner import episode_fn
from app.policy import Policy
from app.sim import SimulationDiverged

RUN = re.compile(
    r"^(?P<task>throw|hammer)_P(?P<P>\d+)_(?P<method>.+)_s(?P<seed>\d+)_(?P<rest>.+)\.csv$"
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", type=Path, required=True, help="a sweep folder (holds runs/)")
    ap.add_argument("--task", choices=["throw", "hammer"], default="throw")
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--command-hold", default="linear")
    ap.add_argument("--objective", default="published")
    ap.add_argument("--against", default="reference")
    ap.add_argument("--levels", type=int, nargs="+", default=[2, 5])
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument(
        "--published",
        type=Path,
        default=None,
        help="the same best θ run through the published simulator "
        "(tests/sim/data/published_optimised_throws.json): adds its J and verdicts",
    )
    args = ap.parse_args()
    suffix = f"{args.preset}_{args.command_hold}_{args.objective}"
    runs = []
    task = args.task
    throw = task == "throw"
    for path in sorted((args.sweep / "runs").glob(f"{task}_P*.csv")):
        m = RUN.match(path.name)
        if not m or m["rest"] != suffix or path.name.endswith(".part.csv"):
            continue
        if int(m["P"]) in args.levels:
            runs.append((int(m["P"]), m["method"], int(m["seed"]), path))
    if not runs:
        sys.exit(f"no finished {task} runs *_{suffix}.csv in {args.sweep / 'runs'}")
    records = []
    t0 = time.perf_counter()
    for i, (levels, method, seed, path) in enumerate(runs, 1):
        rows = read_run(path)
        best = max(rows, key=lambda r: r["objective"] if np.isfinite(r["objective"]) else -1e9)
        theta = np.asarray(best["theta"], dtype=np.float64)
        d = Policy(levels=levels, with_release=throw).decode(np.clip(theta, 0.0, 1.0))
        rec = {
            "P": levels,
            "method": method,
            "seed": seed,
            "trial": int(best["trial"]),
            "release_step": d.release_step,
            "J_sweep": float(best["objective"]),
        }
        for name, preset in (("own", args.preset), ("against", args.against)):
            episode = episode_fn(task, levels, preset, args.command_hold, args.objective)
            try:
                res = episode(theta)
            except SimulationDiverged as exc:
                rec[f"J_{name}"] = None
                rec[f"error_{name}"] = str(exc)
                continue
            rec[f"J_{name}"] = float(res.objective)
            if throw:
                rec[f"lost_{name}"] = res.cube_lost_before_release
                rec[f"D_cube_{name}"] = float(res.objective_terms["cube_distance_m"])
        records.append(rec)
        eta = (time.perf_counter() - t0) / i * (len(runs) - i)
        print(
            f"[{i}/{len(runs)}] P={levels} {method} s{seed}: J {rec['J_own']:.3g} → "
            f"{rec.get('J_against') or float('nan'):.3g}"
            + (f" lost={rec.get('lost_against')}" if throw else "")
            + f" (ETA {eta / 60:.1f} min)",
            file=sys.stderr,
        )
    published = {}
    if args.published:
        published = {c["id"]: c for c in json.loads(args.published.read_text())["cases"]}
    for r in records:
        pub = published.get(f"P{r['P']}_{r['method']}_s{r['seed']}")
        if pub is not None and pub["release_step"] == r["release_step"]:
            r["J_published"] = pub["J_published"]
            r["lost_published"] = pub["cube_lost_before_release"]
    groups: dict[tuple[int, str], list[dict]] = defaultdict(list)
    for r in records:
        groups[(r["P"], r["method"])].append(r)
    print(
        f"\n*best θ of each run: sweep preset {args.preset}, command hold {args.command_hold}, "
        f"scoring rule {args.objective}; replayed in {args.against}"
        + (" (its own grasp)*\n" if throw else "*\n")
    )
    dg = 2 if throw else 3
    if throw:
        print(
            f"| P | method | runs | lost before t_R in {args.against} / published | "
            f"J in {args.preset} | J in {args.against} | J published | "
            f"D_cube {args.preset} / {args.against} (m) |"
        )
        print("|---:|---|---:|---:|---:|---:|---:|---:|")
    else:
        print(
            f"| P | method | runs | J in {args.preset} | J in {args.against} | "
            f"change (mean of the runs') |"
        )
        print("|---:|---|---:|---:|---:|---:|")
    for (levels, method), rs in sorted(groups.items()):
        own = np.array([r["J_own"] for r in rs])
        ag = np.array([np.nan if r.get("J_against") is None else r["J_against"] for r in rs])
        cells = (
            f"{own.mean():.{dg}f} ± {own.std():.{dg}f} | "
            f"{np.nanmean(ag):.{dg}f} ± {np.nanstd(ag):.{dg}f}"
        )
        if not throw:
            print(f"| {levels} | {method} | {len(rs)} | {cells} | {np.nanmean(ag - own):+.{dg}f} |")
            continue
        lost = sum(bool(r.get("lost_against")) for r in rs)
        pub = [r for r in rs if "J_published" in r]
        lost_pub = sum(bool(r["lost_published"]) for r in pub)
        j_pub = np.array([r["J_published"] for r in pub])
        pub_cells = (
            (f"{lost_pub} of {len(pub)}", f"{j_pub.mean():.2f} ± {j_pub.std():.2f}")
            if pub
            else ("–", "–")
        )
        d_own = np.nanmean([r.get("D_cube_own", np.nan) for r in rs])
        d_ag = np.nanmean([r.get("D_cube_against", np.nan) for r in rs])
        print(
            f"| {levels} | {method} | {len(rs)} | {lost} / {pub_cells[0]} | {cells} | "
            f"{pub_cells[1]} | {d_own:.2f} / {d_ag:.2f} |"
        )
    both = [r for r in records if "J_published" in r and r.get("J_against") is not None]
    if both:
        jp = np.array([r["J_published"] for r in both])
        for key, name in (("J_own", args.preset), ("J_against", args.against)):
            j = np.array([r[key] for r in both])
            print(
                f"\n{name} against the published simulator on {len(both)} best throws: "
                f"|ΔJ| mean {np.abs(j - jp).mean():.2f}, median {np.median(np.abs(j - jp)):.2f}, "
                f"mean ΔJ {np.mean(j - jp):+.2f}, correlation {np.corrcoef(j, jp)[0, 1]:.3f}"
            )
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "sweep": str(args.sweep),
                    "task": task,
                    "preset": args.preset,
                    "command_hold": args.command_hold,
                    "objective_rule": args.objective,
                    "against": args.against,
                    "records": records,
                },
                indent=1,
            )
        )


if __name__ == "__main__":
    main()
