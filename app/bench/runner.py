"""One run of a sweep: ``budget`` trials of suggest → decode → rollout → observe, cached trial
by trial so an interrupted run resumes to the same result (suggestions are pure functions of
the data). The simulator runs the plan exactly, so the optimiser observes the planned θ: what
``Policy.executed_theta`` gives, as in the service."""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from app.bench.cache import (
    RUN_COLUMNS,
    cached_rows,
    read_run,
    run_dir,
    run_line,
    write_part,
    write_run,
)
from app.bench.specs import RunSpec
from app.optim import Observation, build_optimizer


def objective_fn(
    task: str,
    levels: int,
    preset: str,
    command_hold: str = "zero",
    objective_rule: str = "paper",
) -> Callable[[np.ndarray], float]:
    """θ (D,) → the task objective of one simulated episode (policy decode → rollout), with
    the commands held or ramped and scored by the rule given (``app.sim.rollout``)."""
    from app.policy import RELEASE_TASKS, Policy
    from app.sim import SimulationDiverged, rollout

    policy = Policy(levels=levels, with_release=task in RELEASE_TASKS)

    def f(theta: np.ndarray) -> float:
        d = policy.decode(np.clip(theta, 0.0, 1.0))
        try:
            res = rollout(
                task,
                d.pressure_schedule_pa,
                release_step=d.release_step,
                preset=preset,
                command_hold=command_hold,
                objective_rule=objective_rule,
            )
        except SimulationDiverged:
            return math.nan
        return float(res.objective)

    return f


def run_one(
    spec: RunSpec,
    out: Path | None = None,
    objective: Callable[[np.ndarray], float] | None = None,
) -> list[dict[str, Any]]:
    """Run (or resume) one optimisation; return its rows (trial, objective, wall_s, theta).

    A diverged simulation counts as the worst value seen so far (0 before any), so the
    optimiser still learns that the point is bad; the row keeps that value. Sets torch's
    threads for this process (``Settings.torch_threads``): runs go side by side instead.
    """
    from app.config import Settings
    from app.procs import set_torch_threads

    set_torch_threads(Settings().torch_threads)
    if out is not None:
        done = cached_rows(spec, out)
        if done is not None:
            return done
    f = objective or objective_fn(
        spec.task, spec.levels, spec.preset, spec.command_hold, spec.objective_rule
    )
    opt = build_optimizer(spec.optimizer_spec())
    rows: list[dict[str, Any]] = []
    part = None
    if out is not None:
        run_dir(out).mkdir(parents=True, exist_ok=True)
        part = run_dir(out) / f"{spec.key}.part.csv"
        shorter = run_dir(out) / f"{spec.key}.csv"  # a finished run with a smaller budget
        start = part if part.exists() else shorter if shorter.exists() else None
        if start is not None:
            rows = read_run(start)[: spec.budget]
            opt.observe_many(Observation(tuple(r["theta"]), r["objective"]) for r in rows)
            if start == shorter and rows:
                write_part(part, rows)
    fh = None
    try:
        if part is not None:
            fresh = not part.exists() or not rows
            fh = open(part, "w" if fresh else "a", newline="")  # noqa: SIM115
            writer = csv.writer(fh)
            if fresh:
                writer.writerow(RUN_COLUMNS)
                fh.flush()
        while len(rows) < spec.budget:
            t0 = time.perf_counter()
            theta = opt.suggest(1)[0]
            value = f(theta)
            if not math.isfinite(value):
                value = min((r["objective"] for r in rows), default=0.0)
            opt.observe(theta, value)
            row = {
                "trial": len(rows) + 1,
                "objective": value,
                "wall_s": time.perf_counter() - t0,
                "theta": [float(v) for v in theta],
            }
            rows.append(row)
            if fh is not None:
                writer.writerow(run_line(row))
                fh.flush()
    finally:
        if fh is not None:
            fh.close()
    if out is not None:
        write_run(spec, out, rows)
    return rows
