"""handful against the published simulator's reference runs, case by case.

Runs every schedule of tests/sim/data/published_reference.json (trimmed from
../shared/fidelity/published_reference_{zoh,foh}.json) through handful with the matching command
hold (zoh → zero, foh → linear) and the published scoring rule, and prints per case: max tip
speed, correlation of the 100 Hz tip-speed traces, J, and (throws) the slip verdict, last pad
contact and D_cube, each beside the published simulator's.

    nice -n 10 python benchmarks/paper_fidelity.py --mode zoh --preset reference
    nice -n 10 python benchmarks/paper_fidelity.py --mode zoh --preset reference --pad-force-n 5
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.sim import ArmParams, rollout_batch
from app.sim.model import effective_params

DATA = Path(__file__).resolve().parents[1] / "tests" / "sim" / "data" / "published_reference.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("zoh", "foh"), default="zoh")
    ap.add_argument("--preset", default="reference")
    ap.add_argument("--grasp", choices=("friction", "weld"), default=None)
    ap.add_argument("--pad-force-n", type=float, default=None)
    ap.add_argument("--noslip-iterations", type=int, default=None)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    params = effective_params(args.preset, ArmParams())
    grip = params.gripper
    for name, value in (
        ("grasp", args.grasp),
        ("pad_force_n", args.pad_force_n),
        ("noslip_iterations", args.noslip_iterations),
    ):
        if value is not None:
            grip = replace(grip, **{name: value})
    params = replace(params, gripper=grip)
    hold = {"zoh": "zero", "foh": "linear"}[args.mode]
    cases = json.loads(DATA.read_text())["modes"][args.mode]
    print(
        f"mode {args.mode} (command_hold {hold}), preset {args.preset}, grasp {grip.grasp}, "
        f"pad force {grip.pad_force_n} N, no-slip iterations {grip.noslip_iterations}; "
        "published rule; each cell: handful / published simulator"
    )
    print("| case | task | t_R | max tip speed (m/s) | Δ | trace corr | J | ΔJ | slipped | "
          "last pad contact (s) | D_cube (m) |")  # fmt: skip
    print("|---:|---|---:|---|---:|---:|---|---:|---|---|---|")
    agree = n_throw = 0
    for task in ("throw", "hammer"):
        mine = [c for c in cases if c["task"] == task]
        results = rollout_batch(
            task,
            [np.array(c["pressures_pa"]) for c in mine],
            release_steps=[c["release_step"] for c in mine] if task == "throw" else None,
            preset=args.preset,
            params=params,
            command_hold=hold,
            objective_rule="published",
            n_workers=args.workers,
        )
        for c, r in zip(mine, results, strict=True):
            ref = np.array(c["tip_speed_100hz"])
            corr = float(np.corrcoef(ref, r.tip_speed_100hz)[0, 1])
            line = (
                f"| {c['id']} | {task} | {c['release_step'] or ''} | "
                f"{r.max_tip_speed:.3f} / {c['max_tip_speed']:.3f} | "
                f"{100 * (r.max_tip_speed / c['max_tip_speed'] - 1):+.1f} % | {corr:.3f} | "
                f"{r.objective:.4g} / {c['J']:.4g} | {100 * (r.objective / c['J'] - 1):+.1f} % |"
            )
            if task == "throw":
                n_throw += 1
                agree += r.cube_lost_before_release == c["cube_lost_before_release"]
                last = "–" if r.last_pad_contact_s is None else f"{r.last_pad_contact_s:.2f}"
                line += (
                    f" {'yes' if r.cube_lost_before_release else 'no'} / "
                    f"{'yes' if c['cube_lost_before_release'] else 'no'} | "
                    f"{last} / {c['last_pad_contact_time_s']:.2f} | "
                    f"{r.objective_terms['cube_distance_m']:.2f} / {c['D_cube']:.2f} |"
                )
            else:
                line += " | | |"
            print(line, flush=True)
    print(f"\nslip verdicts agree on {agree} of {n_throw} throws")


if __name__ == "__main__":
    main()
