"""What one REDQ episode costs on one core, against a `fast` rollout of the same task.

    nice -n 10 python benchmarks/redq_cost.py [--episodes 4] [--json out.json]
        [--device cuda] [--batches 256] [--tasks hammer,throw]

In one process, one torch thread, the paper-matching simulator settings (app.bench.PAPER_*):
the median wall time of a bare ``rollout`` (fast preset) per task; of an environment episode
(``HandfulEnv``, the same physics stepped per control step) with random commands; and of a REDQ
learning episode (10 transitions, 10·UTD gradient updates) with the paper's settings, split into
simulation and learning; then the same with smaller batches. Ratios are what to compare (the
machine may be shared); the 10K projection is 250 random + 9,750 learning episodes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import torch

from app.policy import PAPER_COMMAND_HOLD, PAPER_OBJECTIVE_RULE, PAPER_PRESET
from app.rl.env import HandfulEnv
from app.rl.redq import REDQAgent
from app.rl.settings import REDQSettings
from app.sim import rollout


def timed(fn, n: int) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--json", default=None)
    ap.add_argument("--device", default="cpu", help="torch device of REDQ's networks")
    ap.add_argument("--batches", default="256,64", help="batch sizes to time, e.g. 256")
    ap.add_argument("--tasks", default="hammer,throw")
    args = ap.parse_args()
    batches = [int(b) for b in args.batches.split(",")]
    torch.set_num_threads(1)
    sim = {"preset": PAPER_PRESET, "command_hold": PAPER_COMMAND_HOLD}
    rule = PAPER_OBJECTIVE_RULE
    rng = np.random.default_rng(0)
    out: dict[str, dict[str, float]] = {}
    for task in args.tasks.split(","):
        sched = rng.uniform(0, 1, (10, 12)) * 275_000.0
        release = 10 if task == "throw" else None
        roll = timed(
            lambda t=task, x=sched, r=release: rollout(
                t, x, release_step=r, objective_rule=rule, **sim
            ),
            7,
        )
        env = HandfulEnv(task, objective_rule=rule, **sim)
        act = rng.uniform(0, 1, (10, *env.action_space.shape))

        def env_episode(env: HandfulEnv = env, act: np.ndarray = act) -> None:
            env.reset()
            for a in act:
                env.step(a)

        env_ep = timed(env_episode, 7)
        row = {"rollout_s": roll, "env_episode_s": env_ep}
        for label, batch in ((f"b{b}", b) for b in batches):
            # 260 transitions, then learn
            s = REDQSettings(pretrain_episodes=26, batch_size=batch, device=args.device)
            agent = REDQAgent(env, s, seed=0)
            for _ in range(s.pretrain_episodes):
                agent.run_episode()
            eps = [agent.run_episode() for _ in range(args.episodes)]
            sim_s = statistics.median(e.sim_s for e in eps)
            learn_s = statistics.median(e.learn_s for e in eps)
            total = sim_s + learn_s
            row |= {
                f"redq_{label}_sim_s": sim_s,
                f"redq_{label}_learn_s": learn_s,
                f"redq_{label}_episode_s": total,
                f"redq_{label}_per_update_ms": 1e3 * learn_s / (10 * s.utd),
                f"redq_{label}_vs_rollout": total / roll,
                f"redq_{label}_10k_h": (250 * env_ep + 9750 * total) / 3600,
            }
        row["device"] = args.device  # type: ignore[assignment]
        out[task] = row
        shown = {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}
        print(task, json.dumps(shown), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
