"""Many episodes on all cores: a pool of processes, each holding its own compiled model."""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from app.policy import check_command_hold, check_objective_rule
from app.procs import process_pool
from app.sim.model import effective_params
from app.sim.params import ArmParams
from app.sim.presets import Preset, get_preset
from app.sim.rollout import (
    RolloutResult,
    SimulationDiverged,
    _check_inputs,
    compiled_model,
    rollout,
)

_WORKER: dict[str, Any] = {}  # set once per worker process by its pool's initializer


def _init_worker(
    task: str, preset: Preset, params: ArmParams | None, kwargs: dict[str, Any]
) -> None:
    _WORKER.update(task=task, preset=preset, params=params, kwargs=kwargs)
    # Build (and memoise) the model once per process, before the first episode.
    compiled_model(task, preset, effective_params(preset, params))


def _run_one(item: tuple[int, np.ndarray, int | None]) -> RolloutResult:
    index, schedule, release_step = item
    try:
        return rollout(
            _WORKER["task"],
            schedule,
            release_step=release_step,
            preset=_WORKER["preset"],
            params=_WORKER["params"],
            **_WORKER["kwargs"],
        )
    except SimulationDiverged as exc:
        raise SimulationDiverged(
            f"episode {index}: {exc}", task=exc.task, preset=exc.preset, time_s=exc.time_s
        ) from None


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


class RolloutPool:
    """A reusable pool of worker processes for one (task, preset, params, hold, rule).

    Use as a context manager; ``map`` yields results in input order. ``command_hold`` and
    ``objective_rule`` are as in ``rollout``.
    """

    def __init__(
        self,
        task: str,
        *,
        preset: str | Preset = "reference",
        params: ArmParams | None = None,
        n_workers: int | None = None,
        record_hz: float = 100.0,
        record_qpos: bool = False,
        command_hold: str = "zero",
        objective_rule: str = "paper",
    ) -> None:
        self.task = task
        self.preset = get_preset(preset)
        self.command_hold = check_command_hold(command_hold)
        self.objective_rule = check_objective_rule(objective_rule)
        self.n_workers = default_workers() if n_workers is None else int(n_workers)
        if self.n_workers < 1:
            raise ValueError(f"n_workers must be ≥ 1, got {n_workers}")
        kwargs = {
            "record_hz": record_hz,
            "record_qpos": record_qpos,
            "command_hold": self.command_hold,
            "objective_rule": self.objective_rule,
        }
        self._executor = process_pool(
            self.n_workers, _init_worker, (task, self.preset, params, kwargs)
        )

    def warm_up(self) -> None:
        """Start every worker and build its model now (so timings exclude start-up)."""
        list(self._executor.map(_noop, range(self.n_workers * 2)))

    def map(
        self, schedules: Sequence[np.ndarray], release_steps: Sequence[int | None]
    ) -> Iterator[RolloutResult]:
        """Run each (schedule, release_step); yields RolloutResults in order."""
        pairs = zip(schedules, release_steps, strict=True)
        items = [(i, np.asarray(s, dtype=np.float64), r) for i, (s, r) in enumerate(pairs)]
        # a few items per message, yet ≥ 4 chunks per worker so the load stays balanced
        chunk = max(1, min(8, len(items) // (4 * self.n_workers)))
        return self._executor.map(_run_one, items, chunksize=chunk)

    def close(self) -> None:
        self._executor.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> RolloutPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _noop(_: int) -> None:
    return None


def rollout_batch(
    task: str,
    schedules: np.ndarray | Sequence[np.ndarray],
    *,
    release_steps: Sequence[int | None] | np.ndarray | None = None,
    preset: str | Preset = "reference",
    n_workers: int | None = None,
    progress: bool = False,
    params: ArmParams | None = None,
    record_hz: float = 100.0,
    record_qpos: bool = False,
    command_hold: str = "zero",
    objective_rule: str = "paper",
) -> list[RolloutResult]:
    """Run N episodes, (N, H, 12) schedules in Pa, on ``n_workers`` processes (default: all cores).

    ``release_steps`` (N,) is required for throw; ``command_hold`` and ``objective_rule`` are
    as in ``rollout``. Results come back in input order. With one
    worker (or one episode) everything runs in this process. A diverged episode raises
    SimulationDiverged naming its index.
    """
    sched_list = [np.asarray(s, dtype=np.float64) for s in schedules]
    n = len(sched_list)
    if release_steps is None:
        releases: list[int | None] = [None] * n
    else:
        releases = [None if r is None else int(r) for r in release_steps]
        if len(releases) != n:
            raise ValueError(f"got {n} schedules but {len(releases)} release steps")
    workers = min(default_workers() if n_workers is None else int(n_workers), max(n, 1))
    if workers < 1:
        raise ValueError(f"n_workers must be ≥ 1, got {n_workers}")
    # Validate every input here, before any process starts (one clear error, nothing half-run).
    check_command_hold(command_hold)
    check_objective_rule(objective_rule)
    for i, (s, r) in enumerate(zip(sched_list, releases, strict=True)):
        try:
            _check_inputs(task, s, r, effective_params(preset, params))
        except ValueError as exc:
            raise ValueError(f"episode {i}: {exc}") from None

    bar = _progress(n, progress, task)
    results: list[RolloutResult] = []
    try:
        if workers <= 1:
            for i, (s, r) in enumerate(zip(sched_list, releases, strict=True)):
                try:
                    results.append(
                        rollout(
                            task,
                            s,
                            release_step=r,
                            preset=preset,
                            params=params,
                            record_hz=record_hz,
                            record_qpos=record_qpos,
                            command_hold=command_hold,
                            objective_rule=objective_rule,
                        )
                    )
                except SimulationDiverged as exc:
                    raise SimulationDiverged(
                        f"episode {i}: {exc}", task=exc.task, preset=exc.preset, time_s=exc.time_s
                    ) from None
                bar.update(1)
        else:
            with RolloutPool(
                task,
                preset=preset,
                params=params,
                n_workers=workers,
                record_hz=record_hz,
                record_qpos=record_qpos,
                command_hold=command_hold,
                objective_rule=objective_rule,
            ) as pool:
                for res in pool.map(sched_list, releases):
                    results.append(res)
                    bar.update(1)
    finally:
        bar.close()
    return results


class _NoBar:
    def update(self, _: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress(n: int, enabled: bool, task: str) -> Any:
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=n, desc=f"{task} episodes", unit="ep")
