"""What the friction grasp and the ramped commands cost a throw episode, against today's rollout.

Today's rollout: the welded cube, commands held (``grasp="weld"``, ``command_hold="zero"``).
Each schedule is run in all four combinations back to back (so every ratio comes from the same
minute of the machine), ``--repeats`` times; CPU time of this process (``time.process_time``) is
taken per episode, and the ratio is the median over (schedule, repeat) pairs. ``bare`` rows time the
same physics with no rollout around it (held commands, ``mj_step`` 500 steps at a time in C, no
recording or scoring), so the rollout's own overhead is the difference.

    nice -n 10 python benchmarks/paper_cost.py --preset reference --schedules 4 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numpy as np

from app.policy import Policy
from app.sim import ArmParams, GripperParams, rollout
from app.sim.model import GRIP_ACTUATOR, GRIP_WELD, effective_params
from app.sim.presets import get_preset
from app.sim.rollout import compiled_model

COMBOS = (("weld", "zero"), ("friction", "zero"), ("weld", "linear"), ("friction", "linear"))
BARE = (("weld", "bare"), ("friction", "bare"))


def bare_episode(model: mujoco.MjModel, schedule: np.ndarray, release: int) -> None:
    """The physics of one held-command throw and nothing else (see the module docstring)."""
    data = mujoco.MjData(model)
    grip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, GRIP_ACTUATOR)
    weld = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, GRIP_WELD)
    n_ctrl = round(0.5 / model.opt.timestep)
    for c, row in enumerate(schedule):
        data.ctrl[:12] = row
        if grip >= 0:
            data.ctrl[grip] = 1.0 if c < release else 0.0
        elif c == release:
            data.eq_active[weld] = 0
        mujoco.mj_step(model, data, n_ctrl)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="reference")
    ap.add_argument("--schedules", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--levels", type=int, default=7)
    ap.add_argument("--bare", action="store_true", help="also time the bare physics")
    args = ap.parse_args()
    policy = Policy(levels=args.levels, with_release=True)
    rng = np.random.default_rng(7)
    decoded = [policy.decode(rng.uniform(size=policy.dim)) for _ in range(args.schedules)]
    params = {g: ArmParams(gripper=GripperParams(grasp=g)) for g in ("weld", "friction")}
    for d in decoded[:1]:  # compile every model once, outside the timing
        for g, h in COMBOS:
            rollout("throw", d.pressure_schedule_pa, release_step=d.release_step,
                    preset=args.preset, params=params[g], command_hold=h)  # fmt: skip
    preset = get_preset(args.preset)
    models = {
        g: compiled_model("throw", preset, effective_params(preset, p)) for g, p in params.items()
    }
    combos = COMBOS + (BARE if args.bare else ())
    cpu: dict[tuple[str, str], list[float]] = {c: [] for c in combos}
    for _ in range(args.repeats):
        for d in decoded:
            for g, h in combos:
                t0 = time.process_time()
                if h == "bare":
                    bare_episode(models[g], d.pressure_schedule_pa, d.release_step)
                else:
                    rollout("throw", d.pressure_schedule_pa, release_step=d.release_step,
                            preset=args.preset, params=params[g], command_hold=h)  # fmt: skip
                cpu[(g, h)].append(time.process_time() - t0)
    base = cpu[("weld", "zero")]
    print(f"preset {args.preset}: {len(base)} episodes per combination (CPU s per episode)")
    print("| grasp | command hold | median CPU s | ratio to weld + zero (median of pairs) |")
    print("|---|---|---:|---:|")
    for g, h in combos:
        ratios = [a / b for a, b in zip(cpu[(g, h)], base, strict=True)]
        print(
            f"| {g} | {h} | {statistics.median(cpu[(g, h)]):.3f} | "
            f"{statistics.median(ratios):.3f} |"
        )


if __name__ == "__main__":
    main()
