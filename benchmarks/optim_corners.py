"""Score every corner of the θ box (each step all-low or all-high pressure): the best one.

    python benchmarks/optim_corners.py --task hammer --levels 5 [--preset fast] [--release 0.55]

2^H schedules (1024 at H = 10) through ``rollout_batch`` on all cores; throwing uses one
release θ for all of them.
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np

from app.policy import Policy
from app.sim import rollout_batch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="hammer", choices=("throw", "hammer", "tip_speed"))
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--release", type=float, default=0.55, help="θ of the release step (throw)")
    args = ap.parse_args()
    policy = Policy(levels=args.levels, with_release=args.task == "throw")
    corners = np.array(list(itertools.product([0.0, 1.0], repeat=policy.horizon)))
    if policy.with_release:
        corners = np.concatenate([corners, np.full((len(corners), 1), args.release)], axis=1)
    decoded = [policy.decode(c) for c in corners]
    t0 = time.perf_counter()
    results = rollout_batch(
        args.task,
        np.stack([d.pressure_schedule_pa for d in decoded]),
        release_steps=[d.release_step for d in decoded] if policy.with_release else None,
        preset=args.preset,
        progress=True,
    )
    objective = np.array([r.objective for r in results])
    best = int(np.nanargmax(objective))
    wall = time.perf_counter() - t0
    print(
        f"{args.task} P={args.levels}: {len(objective)} corners in {wall:.0f} s;"
        f" best {objective[best]:.3f} at θ = {corners[best].tolist()},"
        f" median {np.nanmedian(objective):.3f}"
    )


if __name__ == "__main__":
    main()
