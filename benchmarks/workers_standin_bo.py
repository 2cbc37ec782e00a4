"""Tip speed on the stand-in robot with hardware limits: BayesOpt through the server vs random.

1. Random: `--random` θ (default 1000) on the stand-in robot (noise, drift and faults on), under
   the paper's limits (nominal 100 kPa ± 30 kPa, source 205 kPa), P levels; the best tip speed
   measured from the tracking stream among the trials that did not fault.
2. BayesOpt: a hardware tip_speed experiment on a real server (`--method`, `--initial` random
   trials first, as in the paper's 12), run by a real `handful worker hardware --driver standin`
   process; this script plays the operator: suggest, confirm the exact schedule, wait, and send
   faulted trials (needs_review) to failed. It reports the first trial whose measured tip speed
   beats the random best, and the noise-free simulator speeds of both winners.

Usage: python benchmarks/workers_standin_bo.py [--random 1000] [--budget 72] [--initial 12]
           [--levels 5] [--method bo-lei] [--preset fast] [--seed 0]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from workers_common import server, start_worker, stop_worker

from app.client import HandfulClient
from app.policy import Policy, PressureLimits
from app.sim import rollout
from app.workers.drivers import DriverCommand
from app.workers.drivers.standin import StandinDriver
from app.workers.objective import tip_speed_from_tracking

LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0}


def _policy(levels: int) -> Policy:
    return Policy(levels=levels, limits=PressureLimits(**LIMITS))  # type: ignore[arg-type]


def random_chunk(args: tuple[int, int, int, str, int]) -> list[tuple[list[float], float | None]]:
    """Run n random θ on one stand-in robot; (θ, measured tip speed or None if faulted)."""
    n, seed, levels, preset, robot_seed = args
    policy = _policy(levels)
    robot = StandinDriver(seed=robot_seed, state_file="", preset=preset)
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        theta = rng.random(policy.dim)
        cmd = DriverCommand(
            i,
            "tip_speed",
            policy.decode(theta).pressure_schedule_pa,
            None,
            policy.step_s,
            np.asarray(policy.limits.nominal_pa),  # type: ignore[union-attr]
        )
        ex = robot.execute(cmd)
        speed = None if ex.fault else tip_speed_from_tracking(ex.tracking)
        out.append((theta.tolist(), speed))
    return out


def run_random(args: argparse.Namespace) -> list[tuple[list[float], float | None]]:
    """`--random` trials on two stand-in robots in parallel (same noise/drift/fault model)."""
    half = args.random // 2
    jobs = [
        (half, args.seed * 2 + 1, args.levels, args.preset, 101),
        (args.random - half, args.seed * 2 + 2, args.levels, args.preset, 102),
    ]
    with ProcessPoolExecutor(2) as pool:
        return [r for chunk in pool.map(random_chunk, jobs) for r in chunk]


def run_bo(args: argparse.Namespace, root: Path) -> list[dict]:
    """The BayesOpt experiment through the server and a stand-in hardware worker."""
    with server(root / "server") as srv:
        api = HandfulClient(srv.url, token=srv.operator_token, timeout=600)
        worker = start_worker(
            srv,
            "hardware",
            *("--driver", "standin", "-o", f"preset={args.preset}", "-o", "seed=7"),
            *("-o", f"state_file={root / 'standin.json'}"),
            log_name="hardware-worker.log",
        )
        try:
            exp = api.create_experiment(
                name="tip speed, stand-in, hardware limits",
                task="tip_speed",
                target="hardware",
                levels=args.levels,
                method=args.method,
                n_initial=args.initial,
                limits=LIMITS,
                budget=args.budget,
                seed=args.seed,
            )
            for i in range(args.budget):
                t0 = time.perf_counter()
                [trial] = api.suggest(exp["id"], n=1)
                suggest_s = time.perf_counter() - t0
                api.preview_and_confirm(trial)  # the operator's go
                while (t := api.get_trial(trial["id"]))["status"] in ("queued", "running"):
                    time.sleep(0.1)
                if t["status"] == "needs_review":
                    api.resolve_trial(t["id"], "fail", "robot fault: trial void")
                print(
                    f"trial {i + 1:3d}: {t['status']:12s} tip speed "
                    f"{t['objective'] if t['objective'] is not None else float('nan'):.3f} m/s "
                    f"(suggest {suggest_s:.1f} s) {t['status_reason'][:60]}",
                    flush=True,
                )
            return api.list_trials(exp["id"])
        finally:
            stop_worker(worker)


def true_speed(theta: list[float], levels: int, preset: str) -> float:
    """The simulator's own max tip speed for θ: no noise, no drift."""
    sched = _policy(levels).decode(np.asarray(theta)).pressure_schedule_pa
    return rollout("tip_speed", sched, preset=preset).max_tip_speed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--random", type=int, default=1000)
    parser.add_argument("--budget", type=int, default=72)
    parser.add_argument("--initial", type=int, default=12)
    parser.add_argument("--levels", type=int, default=5)
    parser.add_argument("--method", default="bo-lei")
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    t0 = time.perf_counter()
    rand = run_random(args)
    ok = [(th, v) for th, v in rand if v is not None]
    best_theta, best_random = max(ok, key=lambda r: r[1])
    print(
        f"random: {len(rand)} trials, {len(rand) - len(ok)} faulted, best {best_random:.3f} m/s "
        f"({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    with tempfile.TemporaryDirectory(prefix="handful-bench-") as tmp:
        trials = sorted(run_bo(args, Path(tmp)), key=lambda t: t["index"])
    speeds = [t["objective"] for t in trials]
    beat = next((i + 1 for i, v in enumerate(speeds) if v is not None and v > best_random), None)
    done = [t for t in trials if t["objective"] is not None]
    bo_best = max(done, key=lambda t: t["objective"])
    faults = sum(t["status"] == "failed" for t in trials)
    print(f"\nstand-in tip speed, P={args.levels}, preset {args.preset}, method {args.method}")
    print("| | trials | faulted | best measured (m/s) | noise-free sim speed of the best θ (m/s) |")
    print("|---|---|---|---|---|")
    print(
        f"| random | {len(rand)} | {len(rand) - len(ok)} | {best_random:.3f} "
        f"| {true_speed(best_theta, args.levels, args.preset):.3f} |"
    )
    print(
        f"| {args.method} ({args.initial} random first) | {len(trials)} | {faults} "
        f"| {bo_best['objective']:.3f} (trial {bo_best['index']}) "
        f"| {true_speed(bo_best['theta'], args.levels, args.preset):.3f} |"
    )
    print(
        f"\nfirst trial beating the best of {len(rand)} random: "
        + (f"trial {beat} of {len(trials)}" if beat else f"none within {len(trials)}")
    )


if __name__ == "__main__":
    main()
