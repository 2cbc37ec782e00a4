"""One run of a sweep: ``budget`` trials of suggest → decode → rollout → observe, cached trial
by trial so an interrupted run resumes to the same result (suggestions are pure functions of
the data). The simulator runs the plan exactly, so the optimiser observes the planned θ: what
``Policy.executed_theta`` gives, as in the service."""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.bench.cache import (
    RUN_COLUMNS,
    cached_rows,
    read_run,
    run_dir,
    run_line,
    run_lock,
    write_part,
    write_run,
)
from app.bench.specs import HORIZON, RunSpec
from app.optim import Observation, build_optimizer

if TYPE_CHECKING:
    from app.sim import RolloutResult


def _finite_or_worst(value: float, rows: list[dict[str, Any]]) -> float:
    """A trial's objective as the optimiser observes it: a non-finite one (a diverged
    episode) counts as the worst seen so far (0 for the first trial)."""
    if not math.isfinite(value):
        return min((r["objective"] for r in rows), default=0.0)
    return value


def _trial_row(
    rows: list[dict[str, Any]], value: float, t0: float, theta: list[float]
) -> dict[str, Any]:
    """Append the next trial's row to ``rows`` (its time since ``t0``, to the 0.1 ms the cache
    keeps, so a run's rows read the same live and from its cache) and return it."""
    row = {
        "trial": len(rows) + 1,
        "objective": value,
        "wall_s": round(time.perf_counter() - t0, 4),
        "theta": theta,
    }
    rows.append(row)
    return row


def _replaced(fh: Any, path: Path) -> bool:
    """Whether ``path`` is no longer the file ``fh`` writes (deleted, or another file put in
    its place: a ``git checkout``, ``git stash`` or copy over a committed cache)."""
    try:
        now = os.stat(path)
    except FileNotFoundError:
        return True
    mine = os.fstat(fh.fileno())
    return (mine.st_dev, mine.st_ino) != (now.st_dev, now.st_ino)


@contextmanager
def _part_writer(
    part: Path | None, rows: list[dict[str, Any]], *, fresh: bool
) -> Iterator[Callable[[dict[str, Any]], None]]:
    """A function that appends a trial's row (the last of ``rows``) to the run's part file and
    flushes it (a ``fresh`` file gets the header first); without a part file it keeps nothing.

    If the part file was replaced or deleted under the run, the next append writes it anew
    from ``rows`` (every trial so far), so an interruption after that loses nothing; appending
    to the old handle would write to a file no path names any more.
    """
    if part is None:
        yield lambda row: None
        return
    with ExitStack() as files:
        fh = files.enter_context(open(part, "w" if fresh else "a", newline=""))
        writer = csv.writer(fh)
        if fresh:
            writer.writerow(RUN_COLUMNS)
            fh.flush()

        def append(row: dict[str, Any]) -> None:
            nonlocal fh, writer
            if _replaced(fh, part):
                fh.close()
                tmp = part.with_name(part.name + ".tmp")
                write_part(tmp, rows)
                os.replace(tmp, part)
                fh = files.enter_context(open(part, "a", newline=""))
                writer = csv.writer(fh)
                return
            writer.writerow(run_line(row))
            fh.flush()

        yield append


def episode_fn(
    task: str,
    levels: int,
    preset: str,
    command_hold: str = "zero",
    objective_rule: str = "paper",
) -> Callable[[np.ndarray], RolloutResult]:
    """θ (D,) → one simulated episode's RolloutResult (policy decode → rollout), with the
    commands held or ramped and scored by the rule given (``app.sim.rollout``). Raises
    SimulationDiverged as ``rollout`` does."""
    from app.policy import RELEASE_TASKS, Policy
    from app.sim import rollout

    policy = Policy(levels=levels, with_release=task in RELEASE_TASKS)

    def episode(theta: np.ndarray) -> RolloutResult:
        d = policy.decode(np.clip(theta, 0.0, 1.0))
        return rollout(
            task,
            d.pressure_schedule_pa,
            release_step=d.release_step,
            preset=preset,
            command_hold=command_hold,
            objective_rule=objective_rule,
        )

    return episode


def objective_fn(
    task: str,
    levels: int,
    preset: str,
    command_hold: str = "zero",
    objective_rule: str = "paper",
) -> Callable[[np.ndarray], float]:
    """θ (D,) → the task objective of one simulated episode (``episode_fn``); NaN when the
    simulation diverged."""
    from app.sim import SimulationDiverged

    episode = episode_fn(task, levels, preset, command_hold, objective_rule)

    def f(theta: np.ndarray) -> float:
        try:
            return float(episode(theta).objective)
        except SimulationDiverged:
            return math.nan

    return f


def run_one(
    spec: RunSpec,
    out: Path | None = None,
    objective: Callable[[np.ndarray], float] | None = None,
) -> list[dict[str, Any]]:
    """Run (or resume) one optimisation; return its rows (trial, objective, wall_s, theta).
    An RL method's run goes to ``run_rl``.

    A diverged simulation counts as the worst value seen so far (0 before any), so the
    optimiser still learns that the point is bad; the row keeps that value. Sets torch's
    threads for this process (``Settings.torch_threads``): runs go side by side instead.
    """
    from app.config import Settings
    from app.procs import set_torch_threads

    set_torch_threads(Settings().torch_threads)
    if out is None:
        return run_rl(spec) if spec.is_rl else _run_optimiser(spec, None, objective)
    done = cached_rows(spec, out)
    if done is not None:
        return done
    with run_lock(spec, out):  # RunBusy if another process writes this run
        done = cached_rows(spec, out)  # it may have finished while we looked
        if done is not None:
            return done
        return run_rl(spec, out) if spec.is_rl else _run_optimiser(spec, out, objective)


def _run_optimiser(
    spec: RunSpec, out: Path | None, objective: Callable[[np.ndarray], float] | None
) -> list[dict[str, Any]]:
    """``run_one`` for an optimiser, its lock held (``out``) or without a cache."""
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
    fresh = part is not None and (not part.exists() or not rows)
    with _part_writer(part, rows, fresh=fresh) as append:
        while len(rows) < spec.budget:
            t0 = time.perf_counter()
            theta = opt.suggest(1)[0]
            value = _finite_or_worst(f(theta), rows)
            opt.observe(theta, value)
            append(_trial_row(rows, value, t0, [float(v) for v in theta]))
    if out is not None:
        write_run(spec, out, rows)
    return rows


def run_rl(spec: RunSpec, out: Path | None = None) -> list[dict[str, Any]]:
    """Run (or resume) one RL run (REDQ, ``app.rl``; ``run_one`` holds its lock): one episode =
    one trial = one row, whose
    θ is the episode's commands (H rows of 12 pressures as fractions of the maximum, plus the
    gripper command when throwing; rounded to 1e-4) and objective the simulator's.

    Resuming: the agent is checkpointed to ``runs/<key>.agent.pt`` every ``checkpoint_every``
    episodes and at the end (weights, optimisers, replay buffer, random generators). A run
    resumes from the checkpoint, keeping the cached rows up to it (later ones are dropped and
    rerun, exactly as they would have run); without a checkpoint it reruns from episode 1,
    never mixing rows of two agents. A longer budget continues a finished run the same way.
    A diverged episode scores the worst objective so far (0 before any), as in ``run_one``.
    """
    from app.bench.specs import check_rl_settings
    from app.rl.env import HandfulEnv
    from app.rl.redq import REDQAgent

    settings = check_rl_settings(spec.method, spec.settings)
    env = HandfulEnv(
        spec.task,
        joint_states=settings.observations == "joints",
        preset=spec.preset,
        command_hold=spec.command_hold,
        objective_rule=spec.objective_rule,
        horizon=HORIZON,
    )
    agent = REDQAgent(env, settings, seed=spec.seed)
    rows: list[dict[str, Any]] = []
    part = ckpt = None
    if out is not None:
        run_dir(out).mkdir(parents=True, exist_ok=True)
        part = run_dir(out) / f"{spec.key}.part.csv"
        ckpt = run_dir(out) / f"{spec.key}.agent.pt"
        shorter = run_dir(out) / f"{spec.key}.csv"
        start = part if part.exists() else shorter if shorter.exists() else None
        if start is not None and ckpt.exists():
            cached = read_run(start)
            agent.restore(ckpt)
            if len(cached) >= agent.episodes:
                rows = cached[: agent.episodes]
            else:  # a checkpoint ahead of its rows: not ours to trust
                agent = REDQAgent(env, settings, seed=spec.seed)
        write_part(part, rows)
    with _part_writer(part, rows, fresh=False) as append:
        while len(rows) < spec.budget:
            t0 = time.perf_counter()
            ep = agent.run_episode()
            actions = [round(float(v), 4) for v in ep.actions.reshape(-1)]
            value = _finite_or_worst(ep.objective, rows)
            append(_trial_row(rows, value, t0, actions))
            if ckpt is not None and (
                len(rows) % settings.checkpoint_every == 0 or len(rows) == spec.budget
            ):
                agent.save(ckpt)
    if out is not None:
        write_run(spec, out, rows)
    return rows
