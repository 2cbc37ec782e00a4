"""CPU time of a throw or hammer episode in several simulator presets, against the first.

Each random θ (P = ``--levels``) is run in every preset back to back, ``--repeats`` times, so
every ratio comes from the same minute of the machine; the ratio is the median over (θ, repeat)
pairs of the episode's CPU time (``time.process_time``) to the first preset's.

    nice -n 10 python benchmarks/preset_cost.py --presets fast-r1 fast --task throw \\
        --levels 2 7 --schedules 6 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from app.policy import PAPER_COMMAND_HOLD, RELEASE_TASKS, Policy
from app.sim import rollout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["fast-r1", "fast"])
    ap.add_argument("--task", default="throw")
    ap.add_argument("--levels", type=int, nargs="+", default=[2, 7])
    ap.add_argument("--schedules", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--command-hold", default=PAPER_COMMAND_HOLD)
    args = ap.parse_args()
    print(
        f"task {args.task}, command hold {args.command_hold}, {args.schedules} random θ × "
        f"{args.repeats} per P; CPU s per episode (median), ratio to `{args.presets[0]}` "
        "(median of pairs)\n"
    )
    print("| P | " + " | ".join(f"`{p}` CPU s" for p in args.presets) + " | ratio |")
    print("|---:|" + "---:|" * (len(args.presets) + 1))
    for levels in args.levels:
        policy = Policy(levels=levels, with_release=args.task in RELEASE_TASKS)
        rng = np.random.default_rng(7)
        decoded = [policy.decode(rng.uniform(size=policy.dim)) for _ in range(args.schedules)]

        def episode(preset: str, i: int, decoded: list = decoded) -> None:
            d = decoded[i]
            rollout(args.task, d.pressure_schedule_pa, release_step=d.release_step,
                    preset=preset, command_hold=args.command_hold)  # fmt: skip

        for p in args.presets:  # compile every model once, outside the timing
            episode(p, 0)
        cpu: dict[str, list[float]] = {p: [] for p in args.presets}
        for _ in range(args.repeats):
            for i in range(len(decoded)):
                for p in args.presets:
                    t0 = time.process_time()
                    episode(p, i)
                    cpu[p].append(time.process_time() - t0)
        base = cpu[args.presets[0]]
        ratios = [
            "/".join(f"{statistics.median([b / a for a, b in zip(base, cpu[p], strict=True)]):.3f}"
                     for p in args.presets[1:])
        ]  # fmt: skip
        cells = " | ".join(f"{statistics.median(cpu[p]):.4f}" for p in args.presets)
        print(f"| {levels} | {cells} | {ratios[0]} |", flush=True)


if __name__ == "__main__":
    main()
