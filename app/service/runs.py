"""Run a sim trial inside the service (the pre-worker path) and preview schedules.

Both call ``app.sim.rollout`` on exactly the trial's stored schedule; callers run them off
the event loop (a sync route's thread, or the PreviewRunner's pool).
"""

from __future__ import annotations

import threading
import uuid
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.db.base import utcnow
from app.db.models import Preview
from app.db.session import Database
from app.policy import HardwareCeilings, schedule_hash
from app.service import lifecycle as lc
from app.service.artifacts import npz_to_json, store_trajectory
from app.service.audit import record
from app.service.auth import Actor
from app.service.errors import Conflict, NotFound
from app.service.experiments import hold_setting, touch
from app.service.measurements import check_value, store_measurement
from app.service.schemas import PreviewJobRead, TrialRead
from app.service.trials import check_schedule_safe, get_trial


def _trajectory_npz_bytes(result: Any) -> bytes:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trajectory.npz"
        result.trajectory.to_npz(path)
        return path.read_bytes()


def run_trial(db: Database, trial_id: int, *, actor: Actor, artifacts_dir: Path) -> TrialRead:
    """Simulate a queued sim trial now and record its objective and trajectory.

    queued → running (committed) → rollout → completed, or failed when the simulation
    diverges. If the trial was aborted meanwhile the result is dropped.
    """
    from app.sim import SimulationDiverged, rollout

    with db.write() as s:
        trial = get_trial(s, trial_id, for_update=True)
        exp = trial.experiment
        if exp.target != "sim":
            raise Conflict(f"trial #{trial.index} is a hardware trial; a hardware worker runs it")
        lc.check_transition(trial, lc.RUNNING, action="run")
        if trial.status != lc.QUEUED:
            raise lc.IllegalTransition(
                f"cannot run: trial #{trial.index} is {trial.status}, not queued",
                current=trial.status,
            )
        sched = check_schedule_safe(exp, trial.pressure_schedule_pa, trial.release_step)
        release = trial.release_step
        task, preset = exp.task, exp.sim_preset
        trial.attempts += 1
        lc.transition(s, trial, lc.RUNNING, actor=actor.username, action="trial.run")
        touch(exp)
    error = None
    result = None
    try:
        result = rollout(task, sched, release_step=release, preset=preset, record_qpos=True)
    except SimulationDiverged as exc:
        error = f"simulation diverged: {exc}"
    with db.write() as s:
        trial = get_trial(s, trial_id, for_update=True)
        exp = trial.experiment
        if trial.status != lc.RUNNING:  # aborted while it ran
            return TrialRead.build(trial)
        trial.executed_pressure_schedule_pa = np.asarray(sched).tolist()
        trial.executed_release_step = release
        trial.executed_theta = list(trial.theta)
        if result is None:
            lc.transition(
                s,
                trial,
                lc.FAILED,
                actor=actor.username,
                reason=error or "",
                action="trial.run_result",
            )
        else:
            value = float(result.objective)
            check_value(value, exp.objective_unit, exp.objective_unit, what="sim objective")
            store_trajectory(
                s, artifacts_dir, trial, _trajectory_npz_bytes(result), actor=actor, tag="service"
            )
            store_measurement(
                s,
                trial,
                [(value, exp.objective_unit, f"simulated ({preset})")],
                actor=actor,
                source="sim",
            )
            lc.transition(
                s,
                trial,
                lc.COMPLETED,
                actor=actor.username,
                action="trial.run_result",
                detail={
                    "max_tip_speed": float(result.max_tip_speed),
                    "wall_s": float(result.wall_s),
                },
            )
        touch(exp)
        s.flush()
        s.refresh(trial, attribute_names=["artifacts"])
        return TrialRead.build(trial)


# --- previews --------------------------------------------------------------------------------
@dataclass
class PreviewJob:
    """A sim rollout of one trial's schedule, for the operator to look at before confirming."""

    job_id: str
    trial_id: int
    task: str
    preset: str
    schedule: np.ndarray
    release_step: int | None
    schedule_hash: str
    previewed_by: str = ""
    hold: str | None = None
    db: Database | None = None
    status: str = "queued"
    progress: float = 0.0
    error: str | None = None
    result: dict[str, Any] = field(default_factory=dict)

    def read(self, *, with_trajectory: bool = True) -> PreviewJobRead:
        return PreviewJobRead(
            job_id=self.job_id,
            trial_id=self.trial_id,
            status=self.status,  # type: ignore[arg-type]
            progress=self.progress,
            error=self.error,
            predicted_tip_speed=self.result.get("predicted_tip_speed"),
            predicted_objective=self.result.get("predicted_objective"),
            bend_limit_hits=self.result.get("bend_limit_hits"),
            schedule_hash=self.schedule_hash,
            trajectory=self.result.get("trajectory") if with_trajectory else None,
        )


def record_preview(job: PreviewJob) -> None:
    """Store a finished preview (committed, audited): a confirmation is bound to it."""
    assert job.db is not None
    with job.db.write() as s:
        trial = get_trial(s, job.trial_id)
        s.add(
            Preview(
                trial_id=trial.id,
                schedule_hash=job.schedule_hash,
                hold=job.hold,
                sim_preset=job.preset,
                job_id=job.job_id,
                predicted_objective=job.result.get("predicted_objective"),
                previewed_by=job.previewed_by,
                previewed_at=utcnow(),
            )
        )
        record(
            s,
            actor=job.previewed_by,
            action="trial.preview",
            entity="trial",
            entity_id=trial.id,
            experiment_id=trial.experiment_id,
            trial_id=trial.id,
            detail={"schedule_hash": job.schedule_hash, "hold": job.hold, "job_id": job.job_id},
        )
        touch(trial.experiment)
        s.commit()


class PreviewRunner:
    """Runs previews in a thread pool; keeps the last ``max_jobs`` jobs in memory."""

    def __init__(self, workers: int = 1, max_jobs: int = 64) -> None:
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="preview")
        self._jobs: OrderedDict[str, PreviewJob] = OrderedDict()
        self._lock = threading.Lock()
        self._max_jobs = max_jobs

    def submit(
        self,
        db: Database,
        trial_id: int,
        *,
        actor: Actor | None = None,
        ceilings: HardwareCeilings | None = None,
    ) -> PreviewJobRead:
        """Queue a preview of the trial's current schedule (checked against its limits and
        the robot's ceilings). When it has run to the end it is recorded (``previews``: who,
        when, the schedule's hash, the hold setting): what ``actor`` may then confirm."""
        with db.read() as s:
            trial = get_trial(s, trial_id)
            exp = trial.experiment
            sched = check_schedule_safe(
                exp, trial.pressure_schedule_pa, trial.release_step, ceilings=ceilings
            )
            job = PreviewJob(
                job_id=uuid.uuid4().hex,
                trial_id=trial.id,
                task=exp.task,
                preset=exp.sim_preset,
                schedule=sched,
                release_step=trial.release_step,
                schedule_hash=schedule_hash(sched, trial.release_step),
                previewed_by=actor.username if actor is not None else "",
                hold=hold_setting(exp),
                db=db if actor is not None else None,
            )
        with self._lock:
            self._jobs[job.job_id] = job
            while len(self._jobs) > self._max_jobs:
                self._jobs.popitem(last=False)
        self._pool.submit(self._run, job)
        return job.read(with_trajectory=False)

    def _run(self, job: PreviewJob) -> None:
        from app.sim import SimulationDiverged, rollout

        job.status, job.progress = "running", 0.1
        try:
            res = rollout(
                job.task,
                job.schedule,
                release_step=job.release_step,
                preset=job.preset,
                record_qpos=True,
            )
            job.progress = 0.9
            raw = _trajectory_npz_bytes(res)
            job.result = {
                "predicted_tip_speed": float(res.max_tip_speed),
                "predicted_objective": float(res.objective),
                "bend_limit_hits": [int(j) for j in res.bend_limit_hits],
                "trajectory": npz_to_json(raw),
            }
            if job.db is not None:
                record_preview(job)
            job.status, job.progress = "done", 1.0
        except SimulationDiverged as exc:
            job.status, job.error = "error", f"simulation diverged: {exc}"
        except Exception as exc:  # a preview must report, never kill the pool
            job.status, job.error = "error", f"{type(exc).__name__}: {exc}"

    def get(self, job_id: str) -> PreviewJobRead:
        """A job's status, progress and (when done) result."""
        with self._lock:
            job = self._jobs.get(job_id)
        if job is None:
            raise NotFound(f"preview job {job_id} not found (unknown or expired)")
        return job.read()

    def shutdown(self) -> None:
        """Stop taking jobs; running ones finish in the background."""
        self._pool.shutdown(wait=False, cancel_futures=True)


__all__ = ["PreviewJob", "PreviewRunner", "run_trial"]
