"""The sim worker: claims queued sim trials, runs them on all cores, uploads the results.

Protocol (over HTTP only, through `app.client`): claim up to the number of idle processes,
heartbeat every held lease on a thread, run each rollout in a process pool, post the objective,
the executed schedule and the trajectory (npz) to `POST /api/trials/{id}/result`. Transient
HTTP errors are retried (result posts are idempotent per lease); SIGTERM finishes the trials in
flight and exits.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import math
import time
import uuid
from collections.abc import Mapping
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.procs import process_pool
from app.workers.common import (
    LeaseKeeper,
    PermanentError,
    StopFlag,
    StopRequested,
    default_worker_id,
    retry,
)

log = logging.getLogger("handful.worker.sim")


@dataclass
class SimOutcome:
    """What one rollout produced, sent back from the pool process.

    Attributes:
        objective: the task objective, or None when the rollout failed.
        trajectory_npz: compressed npz bytes of the recorded trajectory (or b"").
        fault: None, or one line saying why the rollout failed (diverged, bad input).
        sim_wall_s: seconds the rollout itself took.
        summary: `RolloutResult.to_summary()` (JSON-able), for logs.
    """

    objective: float | None
    trajectory_npz: bytes
    fault: str | None
    sim_wall_s: float
    summary: dict[str, Any] = field(default_factory=dict)


def run_sim_trial(
    task: str,
    pressure_schedule_pa: list[list[float]] | np.ndarray,
    release_step: int | None,
    preset: str,
    record_qpos: bool = True,
    command_hold: str = "zero",
) -> SimOutcome:
    """Run one rollout (in a pool process); never raises for a bad or diverging schedule."""
    from app.sim import SimulationDiverged, rollout

    start = time.perf_counter()
    try:
        res = rollout(
            task,
            np.asarray(pressure_schedule_pa, dtype=np.float64),
            release_step=release_step,
            preset=preset,
            record_qpos=record_qpos,
            command_hold=command_hold,
        )
    except SimulationDiverged as exc:
        return SimOutcome(None, b"", f"simulation diverged: {exc}", time.perf_counter() - start)
    except ValueError as exc:
        return SimOutcome(None, b"", f"simulator refused the schedule: {exc}", 0.0)
    return SimOutcome(
        objective=float(res.objective),
        trajectory_npz=trajectory_npz_bytes(res.trajectory),
        fault=None,
        sim_wall_s=time.perf_counter() - start,
        summary=res.to_summary(),
    )


def trajectory_npz_bytes(trajectory: Any) -> bytes:
    """The trajectory's arrays (the fields `Trajectory.to_npz` writes) as npz bytes.

    Uncompressed on purpose: float64 physics states shrink by only ~7 % under zlib, which costs
    ~20 ms of CPU per episode (14 % of a fast-preset rollout).
    """
    arrays = {
        f.name: getattr(trajectory, f.name)
        for f in dataclasses.fields(trajectory)
        if getattr(trajectory, f.name) is not None
    }
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _warm_up() -> None:
    """Import the simulator in each pool process before the first trial arrives."""
    import app.sim  # noqa: F401


def experiment_preset(experiment: Mapping[str, Any]) -> str:
    """The simulator preset an experiment asks for (``ExperimentRead.sim_preset``)."""
    return str(experiment["sim_preset"])


def experiment_command_hold(experiment: Mapping[str, Any]) -> str:
    """How an experiment's schedule rows are applied (default, and for older servers: zero)."""
    return str(experiment.get("command_hold") or "zero")


@dataclass
class _InFlight:
    lease_id: Any
    trial: dict[str, Any]
    experiment: dict[str, Any]
    started: float


class SimWorker:
    """Claims and runs sim trials until stopped.

    Args:
        client: an `app.client` client holding a worker token.
        max_parallel: rollouts at once (pool processes; default: all cores).
        worker_id: name in the server's audit log.
        poll_s: longest pause between claims when the queue is empty.
        heartbeat_s: heartbeat period; default a third of the lease the server grants.
        record_qpos: upload joint positions too (3D replay on the dashboard).
        prefetch: trials claimed beyond `max_parallel`, waiting in the pool's queue, so a
            process starts its next rollout while the last result is being uploaded.
    """

    def __init__(
        self,
        client: Any,
        *,
        max_parallel: int | None = None,
        worker_id: str | None = None,
        poll_s: float = 1.0,
        heartbeat_s: float | None = None,
        record_qpos: bool = True,
        prefetch: int = 1,
        stop: StopFlag | None = None,
    ) -> None:
        import os

        self.client = client
        self.max_parallel = max(1, int(max_parallel or os.cpu_count() or 1))
        self.worker_id = worker_id or default_worker_id("sim")
        self.poll_s = poll_s
        self.heartbeat_s = heartbeat_s
        self.record_qpos = record_qpos
        self.prefetch = max(0, int(prefetch))
        self.stop = stop or StopFlag()
        self.completed = 0
        self.faulted = 0
        self.refused = 0

    # --- HTTP, with retries ------------------------------------------------------------------
    def _claim(self, n: int) -> list[dict[str, Any]]:
        """Claim up to n trials; waits out a server restart, gives up only when stopping.
        Every retry names the same claim, so one whose answer was lost returns its leases."""
        claim_id = uuid.uuid4().hex
        try:
            return retry(
                lambda: self.client.claim(
                    worker_id=self.worker_id, target="sim", max_trials=n, claim_id=claim_id
                ),
                what="claim",
                stop=self.stop,
                deadline_s=math.inf,
            )
        except StopRequested:
            return []

    def _post(self, job: _InFlight, outcome: SimOutcome) -> None:
        trial_id = job.trial["id"]
        summary = dict(outcome.summary)
        summary.pop("tip_speed_100hz", None)  # the trajectory carries it
        summary["worker_id"] = self.worker_id
        payload = {
            "executed_pressure_schedule_pa": job.trial["pressure_schedule_pa"],
            "executed_release_step": job.trial.get("release_step"),
            "objective": outcome.objective,
            "trajectory_npz": outcome.trajectory_npz or None,
            "fault": outcome.fault,
            "summary": summary,
        }
        try:
            retry(
                lambda: self.client.report_result(trial_id, job.lease_id, **payload),
                what=f"result {trial_id}",
            )
        except PermanentError as exc:
            self.refused += 1
            log.error("result for trial %s refused: %s", trial_id, exc)
            return
        if outcome.fault is None:
            self.completed += 1
        else:
            self.faulted += 1

    # --- the loop ----------------------------------------------------------------------------
    def run(self, *, max_trials: int | None = None, idle_exit_s: float | None = None) -> int:
        """Work until stopped (or `max_trials` done, or idle `idle_exit_s`); return trials run."""
        keeper: LeaseKeeper | None = None
        in_flight: dict[Future[SimOutcome], _InFlight] = {}
        ran = 0
        idle_since = time.monotonic()
        delay = 0.05
        # spawn (no fork after the heartbeat thread starts); gone if this worker is killed
        with process_pool(self.max_parallel, _warm_up) as pool:
            try:
                while True:
                    room = self.max_parallel + self.prefetch - len(in_flight)
                    if max_trials is not None:
                        room = min(room, max_trials - ran - len(in_flight))
                    if room > 0 and not self.stop.is_set():
                        claims = self._claim(room)
                        for claim in claims:
                            if keeper is None:
                                keeper = LeaseKeeper(
                                    lambda lid: self.client.heartbeat(lid),
                                    self.heartbeat_s or _heartbeat_period(claim),
                                )
                                keeper.start()
                            keeper.add(claim["lease_id"])
                            trial, experiment = claim["trial"], claim["experiment"]
                            fut = pool.submit(
                                run_sim_trial,
                                experiment["task"],
                                trial["pressure_schedule_pa"],
                                trial.get("release_step"),
                                experiment_preset(experiment),
                                self.record_qpos,
                                experiment_command_hold(experiment),
                            )
                            in_flight[fut] = _InFlight(
                                claim["lease_id"], trial, experiment, time.monotonic()
                            )
                            log.info("claimed trial %s (lease %s)", trial["id"], claim["lease_id"])
                        if claims:
                            delay = 0.05
                    if not in_flight:
                        if self.stop.is_set() or (max_trials is not None and ran >= max_trials):
                            break
                        if idle_exit_s is not None and time.monotonic() - idle_since > idle_exit_s:
                            break
                        self.stop.wait(delay)
                        delay = min(self.poll_s, delay * 2.0)
                        continue
                    done, _ = wait(list(in_flight), timeout=0.5, return_when=FIRST_COMPLETED)
                    for fut in done:
                        job = in_flight.pop(fut)
                        try:
                            outcome = fut.result()
                        except Exception as exc:  # a crashed pool process
                            outcome = SimOutcome(None, b"", f"worker process failed: {exc}", 0.0)
                        log.info(
                            "ran trial %s lease %s objective %s fault %s sim %.3f s",
                            job.trial["id"],
                            job.lease_id,
                            outcome.objective,
                            outcome.fault,
                            outcome.sim_wall_s,
                        )
                        self._post(job, outcome)
                        assert keeper is not None
                        keeper.remove(job.lease_id)
                        ran += 1
                        idle_since = time.monotonic()
            finally:
                if keeper is not None:
                    keeper.stop()
        return ran


def _heartbeat_period(claim: Mapping[str, Any]) -> float:
    """A third of the lease the server granted (from `lease_expires_at`), at least 0.5 s."""
    from datetime import UTC, datetime

    expires = claim.get("lease_expires_at")
    try:
        when = datetime.fromisoformat(str(expires).replace("Z", "+00:00"))
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)
        left = (when - datetime.now(UTC)).total_seconds()
    except ValueError:
        left = 30.0
    return max(0.5, left / 3.0)
