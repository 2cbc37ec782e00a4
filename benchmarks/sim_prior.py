"""From simulation to the robot: hardware trials to reach the best of 1000 random ones, on
stand-in robots with a reality gap, with and without a sim prior (issue 18).

Setup (the paper's real-robot experiment): the tip-speed task, P levels (5), H = 10, the
hardware limits (all chambers at 100 kPa nominal, at most ± 30 kPa, source 205 kPa: the
stand-in's ``HardwareCeilings``), command hold ``zero`` (the experiment default), the simulator
preset ``--preset`` (``fast``), on each of ``--instances`` stand-in robots (``standin`` driver,
``gap=--gap``, ``instance=1..``: their own stiffness, damping, pressure lags, link masses, tip
load and friction; tracker noise and drift on; faults off, so every trial gives a number).

1. Target, per instance: the best measured tip speed of ``--random`` uniformly random θ run on a
   fresh robot of that instance (drift runs on through the 1000 trials).
2. Sim prior, per seed: a sim experiment on the nominal simulator: the same optimiser and
   policy, 12 Sobol + 60 BO trials, objective the simulator's noise-free max tip speed.
3. Hardware runs, per instance × seed × method, on a fresh robot: ``none`` (no prior),
   ``multitask`` and ``warmstart`` (``prior_mode``; see ``app.optim.prior``), each built by
   ``app.optim.build_optimizer`` as the service builds it (``bo-lei-default``, n_initial 12,
   ``prior_top_k`` 2), capped at 72 trials (12 + 60); a run stops at the first trial whose
   measured tip speed reaches the instance's target. Score: that trial's number (> 72: never).

Everything is cached as JSON under ``--out`` (one file per target, prior and run), so a rerun
resumes; CPU seconds are recorded per piece. One process, torch on one thread.

Usage: python benchmarks/sim_prior.py [--instances 5] [--seeds 3] [--gap 1.0] [--random 1000]
           [--levels 5] [--preset fast] [--out bench_out/sim_prior]
           [--write docs/bench/sim_to_real.md]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.optim import OptimizerSpec, PriorData, build_optimizer
from app.policy import Policy, PressureLimits
from app.procs import set_torch_threads
from app.sim import rollout
from app.workers.drivers import DriverCommand
from app.workers.drivers.standin import StandinDriver
from app.workers.objective import tip_speed_from_tracking

LIMITS = {"nominal_pa": (100_000.0,), "max_step_pa": 30_000.0, "source_pa": 205_000.0}
METHOD = "bo-lei-default"  # the service's default method
N_INITIAL, N_BO = 12, 60
BUDGET = N_INITIAL + N_BO
HOLD = "zero"
MODES = ("none", "multitask", "warmstart")


def policy(levels: int) -> Policy:
    return Policy(levels=levels, limits=PressureLimits(**LIMITS))  # type: ignore[arg-type]


def robot(args: argparse.Namespace, instance: int, seed: int) -> StandinDriver:
    return StandinDriver(
        seed=seed,
        instance=instance,
        gap=args.gap,
        state_file="",
        preset=args.preset,
        fault_probability=0.0,
        tracker_loss_probability=0.0,
    )


def measure(drv: StandinDriver, pol: Policy, theta: np.ndarray, k: int) -> float:
    cmd = DriverCommand(
        k,
        "tip_speed",
        pol.decode(theta).pressure_schedule_pa,
        None,
        pol.step_s,
        np.asarray(pol.limits.nominal_pa),  # type: ignore[union-attr]
        command_hold=HOLD,
    )
    return tip_speed_from_tracking(drv.execute(cmd).tracking)


def cached(path: Path, make: Any) -> dict[str, Any]:
    if path.exists():
        return json.loads(path.read_text())
    t0 = time.process_time()
    out = make()
    out["cpu_s"] = round(time.process_time() - t0, 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out))
    tmp.replace(path)
    print(f"{path.name}: {out.get('summary', '')} ({out['cpu_s']} s CPU)", flush=True)
    return out


def random_target(args: argparse.Namespace, instance: int) -> dict[str, Any]:
    pol = policy(args.levels)
    drv = robot(args, instance, seed=20_000 + instance)
    rng = np.random.default_rng([7, instance])
    thetas = rng.random((args.random, pol.dim))
    speeds = [measure(drv, pol, th, k) for k, th in enumerate(thetas)]
    i = int(np.argmax(speeds))
    return {
        "target": speeds[i],
        "best_trial": i + 1,
        "best_theta": thetas[i].tolist(),
        "median": float(np.median(speeds)),
        "gap": drv.gap_draw,
        "summary": f"instance {instance}: best of {args.random} random {speeds[i]:.3f} m/s",
    }


def spec(args: argparse.Namespace, seed: int, prior: PriorData | None, mode: str) -> OptimizerSpec:
    return OptimizerSpec(
        METHOD,
        levels=args.levels,
        horizon=10,
        with_release=False,
        seed=seed,
        settings={} if prior is None else {"prior_mode": mode},
        n_initial=N_INITIAL,
        prior=prior,
    )


def sim_prior(args: argparse.Namespace, seed: int) -> dict[str, Any]:
    """A sim experiment on the nominal simulator: 12 Sobol + 60 BO, noise-free tip speed."""
    pol = policy(args.levels)
    opt = build_optimizer(spec(args, 1000 + seed, None, "none"))
    for _ in range(BUDGET):
        th = opt.suggest(1)[0]
        sched = pol.decode(th).pressure_schedule_pa
        res = rollout("tip_speed", sched, preset=args.preset, command_hold=HOLD)
        opt.observe(th, res.objective)
    x, y, _ = opt.train_data()
    return {
        "theta": x.tolist(),
        "objective": y.tolist(),
        "summary": f"seed {seed}: sim best {y.max():.3f} m/s at trial {int(np.argmax(y)) + 1}",
    }


def hardware_run(
    args: argparse.Namespace, instance: int, seed: int, mode: str, target: float, prior: PriorData
) -> dict[str, Any]:
    pol = policy(args.levels)
    drv = robot(args, instance, seed=10_000 + 100 * instance + seed)
    opt = build_optimizer(spec(args, seed, None if mode == "none" else prior, mode))
    speeds: list[float] = []
    steps: list[str] = []
    corr: list[float | None] = []
    reached = None
    for k in range(BUDGET):
        th = opt.suggest(1)[0]
        basis = opt.suggestion_basis()
        steps.append(basis["steps"][0])
        corr.append(basis["task_correlation"])
        v = measure(drv, pol, th, k)
        opt.observe(th, v)
        speeds.append(v)
        if v >= target:
            reached = k + 1
            break
    return {
        "reached": reached,
        "speeds": speeds,
        "steps": steps,
        "task_correlation": corr,
        "summary": f"instance {instance} seed {seed} {mode}: "
        + (f"trial {reached}" if reached else f"not within {BUDGET}"),
    }


def score(run: dict[str, Any]) -> int:
    """Trials to the target; BUDGET + 1 when never reached (sorts as 'more than 72')."""
    return run["reached"] if run["reached"] is not None else BUDGET + 1


def fmt(n: float) -> str:
    return f"> {BUDGET}" if n > BUDGET else (f"{n:g}")


def report(args: argparse.Namespace, targets, priors, runs, cpu_s: float) -> str:
    lines = [
        f"stand-in gap {args.gap:g}, instances 1..{args.instances}, seeds 0..{args.seeds - 1}, "
        f"P={args.levels}, H=10, preset {args.preset}, command hold {HOLD}, tip speed "
        f"(max of the tracked, 3-sample-smoothed tip speed), {METHOD}, "
        f"cap {N_INITIAL} + {N_BO}",
        "",
        "| instance | target: best of "
        f"{args.random} random (m/s) | sim prior's best θ measured here (m/s) | "
        + " | ".join(f"{m}: trials per seed" for m in MODES)
        + " | "
        + " | ".join(f"{m} median" for m in MODES)
        + " |",
        "|---" * (3 + 2 * len(MODES)) + "|",
    ]
    worse = []
    for inst in range(1, args.instances + 1):
        t = targets[inst]
        per = {m: [score(runs[(inst, s, m)]) for s in range(args.seeds)] for m in MODES}
        med = {m: statistics.median(v) for m, v in per.items()}
        first = [runs[(inst, s, "warmstart")]["speeds"][0] for s in range(args.seeds)]
        for m in ("multitask", "warmstart"):
            if med[m] > med["none"]:
                worse.append(f"{m} on instance {inst} ({fmt(med[m])} vs {fmt(med['none'])})")
        lines.append(
            f"| {inst} | {t['target']:.3f} | "
            + ", ".join(f"{v:.3f}" for v in first)
            + " | "
            + " | ".join(", ".join(fmt(v) for v in per[m]) for m in MODES)
            + " | "
            + " | ".join(fmt(med[m]) for m in MODES)
            + " |"
        )
    allmed = {
        m: statistics.median(
            score(runs[(i, s, m)]) for i in range(1, args.instances + 1) for s in range(args.seeds)
        )
        for m in MODES
    }
    reached = {
        m: sum(
            runs[(i, s, m)]["reached"] is not None
            for i in range(1, args.instances + 1)
            for s in range(args.seeds)
        )
        for m in MODES
    }
    n = args.instances * args.seeds
    lines += [
        "",
        "| | " + " | ".join(MODES) + " |",
        "|---" * (1 + len(MODES)) + "|",
        "| median trials to target, all runs | " + " | ".join(fmt(allmed[m]) for m in MODES) + " |",
        "| runs that reached it | " + " | ".join(f"{reached[m]} / {n}" for m in MODES) + " |",
        "",
        "sim priors (nominal simulator, 12 Sobol + 60 BO, noise-free): "
        + "; ".join(
            f"seed {s}: best {max(p['objective']):.3f} m/s" for s, p in sorted(priors.items())
        ),
        "per-instance medians worse than without the prior: " + ("; ".join(worse) or "none"),
        f"CPU: {cpu_s / 60:.1f} min in all (cached pieces included)",
    ]
    corr = [
        c
        for (_, _, m), r in runs.items()
        if m == "multitask"
        for c in r["task_correlation"]
        if c is not None
    ]
    if corr:
        lines.append(
            f"multitask GP's learned sim↔hardware correlation over its model steps: median "
            f"{statistics.median(corr):.2f}, range {min(corr):.2f} .. {max(corr):.2f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--instances", type=int, default=5)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--gap", type=float, default=1.0)
    ap.add_argument("--random", type=int, default=1000)
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--out", type=Path, default=Path("bench_out/sim_prior"))
    ap.add_argument("--write", type=Path, help="also write the report to this file")
    ap.add_argument("--only", choices=("targets", "priors", "runs"), help="compute only this stage")
    args = ap.parse_args(argv)
    set_torch_threads(1)
    out = args.out / f"gap{args.gap:g}_P{args.levels}_{args.preset}"
    # instance by instance (its target, then its runs), so a stopped run leaves whole instances
    targets: dict[int, dict[str, Any]] = {}
    priors: dict[int, dict[str, Any]] = {}
    runs: dict[tuple[int, int, str], dict[str, Any]] = {}
    for i in range(1, args.instances + 1):
        targets[i] = cached(out / f"target_{i}.json", lambda i=i: random_target(args, i))
        for s in range(args.seeds):
            if s not in priors:
                priors[s] = cached(out / f"prior_{s}.json", lambda s=s: sim_prior(args, s))
            p = priors[s]
            prior = PriorData(p["theta"], p["objective"], source=f"sim seed {s}")
            for m in ("multitask", "warmstart", "none"):
                runs[(i, s, m)] = cached(
                    out / f"run_{m}_{i}_{s}.json",
                    lambda i=i, s=s, m=m, prior=prior: hardware_run(
                        args, i, s, m, targets[i]["target"], prior
                    ),
                )
    cpu = sum(d["cpu_s"] for d in [*targets.values(), *priors.values(), *runs.values()])
    text = report(args, targets, priors, runs, cpu)
    print(text)
    if args.write:
        args.write.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
