"""Run a sim trial inside the service (the pre-worker path) and preview schedules.

Both call ``app.sim.rollout`` on exactly the trial's stored schedule; callers run them off
the event loop (a sync route's thread, or the PreviewRunner's pool).
"""

from __future__ import annotations

import logging
import threading
import uuid
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import Lease, Preview
from app.db.session import Database
from app.policy import HardwareCeilings, schedule_hash
from app.service import lifecycle as lc
from app.service.artifacts import npz_to_json, store_trajectory
from app.service.audit import record
from app.service.auth import Actor
from app.service.errors import InvalidInput, NotFound
from app.service.experiments import executed_theta, touch
from app.service.leases import SERVICE_WORKER, open_lease
from app.service.measurements import check_value, store_measurement
from app.service.schemas import PreviewJobRead, TrialRead
from app.service.trials import check_schedule_safe, get_trial, lock_for

log = logging.getLogger("handful.runs")


def simulate(what: ServiceRun | PreviewJob) -> Any:
    """The one simulation of a trial's schedule, for a run in the service and for a preview
    alike (so a preview shows what a run does): the experiment's task, preset and command hold,
    the arm's pose recorded for the 3D replay. Returns the ``app.sim.RolloutResult``."""
    from app.sim import rollout

    return rollout(
        what.task,
        what.schedule,
        release_step=what.release_step,
        preset=what.preset,
        record_qpos=True,
        command_hold=what.command_hold,
    )


def _trajectory_npz_bytes(result: Any) -> bytes:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trajectory.npz"
        result.trajectory.to_npz(path)
        return path.read_bytes()


@dataclass(frozen=True)
class ServiceRun:
    """A sim trial the service has started running, under its own lease."""

    trial_id: int
    lease_id: str
    task: str
    preset: str
    schedule: np.ndarray
    release_step: int | None
    command_hold: str


def start_run(
    session: Session,
    trial_id: int,
    *,
    actor: Actor,
    lease_seconds: float,
    now: datetime | None = None,
) -> ServiceRun:
    """queued → running under a lease held by the service (flushed; the caller commits).

    Everything ``rollout`` would refuse (a horizon whose control step is not a whole number of
    physics steps, a bad release step) is refused here as InvalidInput, the trial untouched.
    If the server dies before ``finish_run`` the lease stops being renewed and the sweep
    fails the trial with the reason (``app.service.leases.sweep_expired``).
    """
    from app.sim import check_rollout

    now = now or utcnow()
    trial = lock_for(
        session,
        trial_id,
        target="sim",
        source=lc.QUEUED,
        dest=lc.RUNNING,
        action="run",
        other_target="a hardware worker runs it",
    )
    exp = trial.experiment
    sched = check_schedule_safe(exp, trial.pressure_schedule_pa, trial.release_step)
    try:
        check_rollout(exp.task, sched, release_step=trial.release_step, preset=exp.sim_preset)
    except ValueError as exc:
        raise InvalidInput(f"trial #{trial.index} cannot be simulated: {exc}") from None
    lease = open_lease(
        session,
        trial,
        worker_id=SERVICE_WORKER,
        actor=actor,
        action="trial.run",
        lease_seconds=lease_seconds,
        now=now,
    )
    return ServiceRun(
        trial.id,
        lease.id,
        exp.task,
        exp.sim_preset,
        sched,
        trial.release_step,
        exp.command_hold,
    )


def renew_run(
    session: Session, run: ServiceRun, *, lease_seconds: float, now: datetime | None = None
) -> bool:
    """Extend the run's lease (flushed); False once it is no longer active (aborted)."""
    now = now or utcnow()
    lease = session.get(Lease, run.lease_id)
    if lease is None or lease.status != "active":
        return False
    lease.heartbeat_at = now
    lease.expires_at = now + timedelta(seconds=lease_seconds)
    session.flush()
    return True


def finish_run(
    session: Session,
    run: ServiceRun,
    result: Any,
    error: str | None,
    *,
    actor: Actor,
    artifacts_dir: Path,
    now: datetime | None = None,
) -> TrialRead:
    """Record a service run's outcome: completed with its objective and trajectory, or failed
    with ``error``; the lease ends. A trial aborted meanwhile keeps its state (result dropped)."""
    now = now or utcnow()
    trial = get_trial(session, run.trial_id, for_update=True)
    exp = trial.experiment
    lease = session.get(Lease, run.lease_id)
    if trial.status != lc.RUNNING or lease is None or lease.status != "active":
        return TrialRead.build(trial)  # aborted (or its lease swept) while it ran
    lease.status = "completed"
    lease.ended_at = now
    trial.executed_pressure_schedule_pa = np.asarray(run.schedule).tolist()
    trial.executed_release_step = run.release_step
    trial.executed_theta = executed_theta(exp, trial.theta, run.schedule, run.release_step)
    value = None if result is None else float(result.objective)
    if value is not None and error is None:
        try:
            check_value(value, exp.objective_unit, exp.objective_unit, what="sim objective")
        except InvalidInput as exc:
            error = f"the simulator returned an unusable objective: {exc}"
    if result is None or error is not None:
        lc.transition(
            session,
            trial,
            lc.FAILED,
            actor=actor.username,
            reason=error or "the simulator returned nothing",
            action="trial.run_result",
            now=now,
        )
    else:
        assert value is not None
        store_trajectory(
            session, artifacts_dir, trial, _trajectory_npz_bytes(result), actor=actor, tag="service"
        )
        store_measurement(
            session,
            trial,
            [(value, exp.objective_unit, f"simulated ({run.preset})")],
            actor=actor,
            source="sim",
        )
        lc.transition(
            session,
            trial,
            lc.COMPLETED,
            actor=actor.username,
            action="trial.run_result",
            detail={
                "max_tip_speed": float(result.max_tip_speed),
                "wall_s": float(result.wall_s),
            },
            now=now,
        )
    touch(exp)
    session.flush()
    session.refresh(trial, attribute_names=["artifacts"])
    return TrialRead.build(trial)


def run_trial(
    db: Database, trial_id: int, *, actor: Actor, artifacts_dir: Path, lease_seconds: float = 60.0
) -> TrialRead:
    """Simulate a queued sim trial now and record its objective and trajectory.

    queued → running (committed, under a service lease renewed every third of
    ``lease_seconds`` while the simulator runs) → completed, or failed with the reason when
    the simulation diverges or the simulator raises. If the trial was aborted meanwhile the
    result is dropped; if this process dies, the lease sweep fails the trial.
    """
    from app.sim import SimulationDiverged

    with db.write() as s:
        run = start_run(s, trial_id, actor=actor, lease_seconds=lease_seconds)
    stop = threading.Event()

    def renew() -> None:
        while not stop.wait(lease_seconds / 3):
            try:
                with db.write() as s:
                    if not renew_run(s, run, lease_seconds=lease_seconds):
                        return
            except Exception:  # a busy database: try again at the next beat
                log.warning("could not renew the lease of service run %s", run.lease_id)

    beats = threading.Thread(target=renew, name=f"run-{trial_id}", daemon=True)
    beats.start()
    error = None
    result = None
    try:
        result = simulate(run)
    except SimulationDiverged as exc:
        error = f"simulation diverged: {exc}"
    except Exception as exc:  # whatever went wrong, the trial must not stay running
        log.exception("service run of trial %d failed", trial_id)
        error = f"the simulator failed: {type(exc).__name__}: {exc}"
    finally:
        stop.set()
        beats.join()
    with db.write() as s:
        return finish_run(s, run, result, error, actor=actor, artifacts_dir=artifacts_dir)


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
    command_hold: str = "zero"
    previewed_by: str = ""
    db: Database | None = None
    status: str = "queued"
    progress: float = 0.0
    error: str | None = None
    result: dict[str, Any] = field(default_factory=dict)

    def read(self, *, with_trajectory: bool = True) -> PreviewJobRead:
        return PreviewJobRead(
            job_id=self.job_id,
            trial_id=self.trial_id,
            status=self.status,
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
                hold=job.command_hold,
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
            detail={
                "schedule_hash": job.schedule_hash,
                "hold": job.command_hold,
                "job_id": job.job_id,
            },
        )
        touch(trial.experiment)


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
                command_hold=exp.command_hold,
                schedule=sched,
                release_step=trial.release_step,
                schedule_hash=schedule_hash(sched, trial.release_step),
                previewed_by=actor.username if actor is not None else "",
                db=db if actor is not None else None,
            )
        with self._lock:
            self._jobs[job.job_id] = job
            while len(self._jobs) > self._max_jobs:
                self._jobs.popitem(last=False)
        self._pool.submit(self._run, job)
        return job.read(with_trajectory=False)

    def _run(self, job: PreviewJob) -> None:
        from app.sim import SimulationDiverged

        job.status, job.progress = "running", 0.1
        try:
            res = simulate(job)
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


__all__ = [
    "SERVICE_WORKER",
    "PreviewJob",
    "PreviewRunner",
    "ServiceRun",
    "finish_run",
    "renew_run",
    "run_trial",
    "start_run",
]
