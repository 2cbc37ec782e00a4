"""Sim twins: every hardware trial gets a simulated run of exactly its schedule, stored beside it.

Two per trial (``TrialTwin.kind``): "planned", the schedule the optimiser proposed, made as soon
as the trial exists so the operator sees the twin's prediction next to the GP's at the safety
gate; and "executed", the schedule the robot reports it ran (when it equals the plan, the
planned twin's numbers are reused). A twin runs with the hardware experiment's command hold
and the preset of its linked sim experiment (``app.service.sim_prior.twin_preset``; the
paper-matching ``fast`` without one), scored by the rule the sim workers use, so twin and
sim prior are the same simulator.

Where twins run: in the server, on ``TwinRunner``'s own background thread (as previews run
their rollouts on the server's threads), polling for hardware trials without their twins.
Not as sim-worker leases, because a twin is not a trial (it must enter no sim experiment, no
budget and no optimiser, and the worker protocol stays as it is) and it must be there at the
gate even when no sim worker is connected. Not in the compute processes either (the first
design): for an experiment whose optimiser runs inline (random, CEM) that started a compute
process, torch's import and all, while a hardware trial ran, and the hardware worker's
heartbeats on 1 s leases were starved (tests/workers/test_workers_e2e.py). One ``fast``
rollout takes ~0.15 s; ``run_pending(call=...)`` still takes any runner (e.g.
``ComputeRunner.call``) should twins grow costlier.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import and_, exists, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import Experiment, Trial, TrialTwin
from app.db.session import Database
from app.policy import schedule_hash
from app.service import lifecycle as lc
from app.service.experiments import get_experiment, touch_id
from app.service.schemas import TwinComparisonRead, TwinRead
from app.service.sim_prior import TWIN_OBJECTIVE_RULE, twin_preset

log = logging.getLogger("handful.twins")

PLANNED, EXECUTED = "planned", "executed"
#: a twin whose compute call failed (not the simulator: a stopped process) is retried this
#: many times, then stored as an error
MAX_ATTEMPTS = 3


@dataclass(frozen=True)
class TwinJob:
    """One twin to simulate: a trial's schedule and the settings it runs with."""

    trial_id: int
    experiment_id: int
    kind: str
    task: str
    schedule_pa: tuple[tuple[float, ...], ...]
    release_step: int | None
    preset: str
    command_hold: str
    objective_rule: str
    sim_experiment_id: int | None
    schedule_hash: str


def simulate(job: TwinJob) -> dict[str, Any]:
    """Run the twin (in a compute process): the simulator's prediction, or its error."""
    t0 = time.perf_counter()
    try:
        from app.sim import SimulationDiverged, rollout
    except ImportError as exc:  # a hardware-only server without MuJoCo
        return {"status": "error", "error": f"the simulator is not installed here: {exc}"}
    try:
        res = rollout(
            job.task,
            np.asarray(job.schedule_pa, dtype=np.float64),
            release_step=job.release_step,
            preset=job.preset,
            command_hold=job.command_hold,
            objective_rule=job.objective_rule,
        )
    except SimulationDiverged as exc:
        return {"status": "error", "error": f"simulation diverged: {exc}"}
    except ValueError as exc:
        return {"status": "error", "error": f"the simulator refused the schedule: {exc}"}
    return {
        "status": "done",
        "predicted_objective": float(res.objective),
        "predicted_tip_speed": float(res.max_tip_speed),
        "bend_limit_hits": [int(j) for j in res.bend_limit_hits],
        "wall_s": time.perf_counter() - t0,
    }


# --- what is missing -----------------------------------------------------------------------------
def _missing(kind: str) -> Any:
    return ~exists().where(and_(TrialTwin.trial_id == Trial.id, TrialTwin.kind == kind))


def pending_jobs(session: Session, *, limit: int = 8) -> list[TwinJob]:
    """Twins still to make, oldest trial first: a planned twin for each hardware trial not yet
    run, an executed twin for each one with an executed schedule."""
    q = (
        select(Trial)
        .join(Experiment, Trial.experiment_id == Experiment.id)
        .where(
            Experiment.target == "hardware",
            (
                (Trial.status.in_(lc.PENDING) & _missing(PLANNED))
                | (Trial.executed_pressure_schedule_pa.is_not(None) & _missing(EXECUTED))
            ),
        )
        .order_by(Trial.id)
        .limit(limit)
    )
    jobs = []
    for trial in session.scalars(q):
        job = job_for(session, trial)
        if job is not None:
            jobs.append(job)
    return jobs


def job_for(session: Session, trial: Trial) -> TwinJob | None:
    """The twin ``trial`` needs next (executed once it ran, else planned), or None."""
    exp = trial.experiment
    have = set(session.scalars(select(TrialTwin.kind).where(TrialTwin.trial_id == trial.id)))
    if trial.executed_pressure_schedule_pa is not None and EXECUTED not in have:
        kind, sched, release = (
            EXECUTED,
            trial.executed_pressure_schedule_pa,
            trial.executed_release_step if exp.with_release else None,
        )
    elif trial.status in lc.PENDING and PLANNED not in have:
        kind, sched, release = PLANNED, trial.pressure_schedule_pa, trial.release_step
    else:
        return None
    preset = twin_preset(session, exp)
    return TwinJob(
        trial_id=trial.id,
        experiment_id=exp.id,
        kind=kind,
        task=exp.task,
        schedule_pa=tuple(tuple(float(v) for v in row) for row in sched),
        release_step=release,
        preset=preset,
        command_hold=exp.command_hold,
        objective_rule=TWIN_OBJECTIVE_RULE,
        sim_experiment_id=exp.sim_prior_experiment_id,
        schedule_hash=schedule_hash(sched, release),
    )


def reusable(session: Session, job: TwinJob) -> dict[str, Any] | None:
    """An executed twin whose schedule the planned twin already simulated with the same
    settings: its numbers (the robot ran its plan), else None."""
    if job.kind != EXECUTED:
        return None
    planned = session.scalar(
        select(TrialTwin).where(TrialTwin.trial_id == job.trial_id, TrialTwin.kind == PLANNED)
    )
    if planned is None or planned.status != "done":
        return None
    same = (planned.schedule_hash, planned.sim_preset, planned.command_hold) == (
        job.schedule_hash,
        job.preset,
        job.command_hold,
    )
    if not same or planned.objective_rule != job.objective_rule:
        return None
    return {
        "status": "done",
        "predicted_objective": planned.predicted_objective,
        "predicted_tip_speed": planned.predicted_tip_speed,
        "bend_limit_hits": planned.bend_limit_hits,
        "wall_s": 0.0,
    }


def store(session: Session, job: TwinJob, outcome: dict[str, Any]) -> TrialTwin | None:
    """Store a twin (flushed; the experiment's version moves so the pages redraw); None when
    one of this kind is there already (another server stored it meanwhile)."""
    if session.scalar(
        select(TrialTwin.id).where(TrialTwin.trial_id == job.trial_id, TrialTwin.kind == job.kind)
    ):
        return None
    if session.get(Trial, job.trial_id) is None:
        return None
    twin = TrialTwin(
        trial_id=job.trial_id,
        kind=job.kind,
        schedule_hash=job.schedule_hash,
        sim_preset=job.preset,
        command_hold=job.command_hold,
        objective_rule=job.objective_rule,
        sim_experiment_id=job.sim_experiment_id,
        status=outcome.get("status", "error"),
        error=outcome.get("error"),
        predicted_objective=outcome.get("predicted_objective"),
        predicted_tip_speed=outcome.get("predicted_tip_speed"),
        bend_limit_hits=outcome.get("bend_limit_hits"),
        wall_s=outcome.get("wall_s"),
        created_at=utcnow(),
    )
    session.add(twin)
    touch_id(session, job.experiment_id)
    session.flush()
    return twin


Call = Callable[[TwinJob], dict[str, Any]]


def run_pending(
    db: Database,
    *,
    call: Call | None = None,
    limit: int = 8,
    failures: dict[tuple[int, str], int] | None = None,
) -> int:
    """Make up to ``limit`` missing twins; return how many were stored. ``call(job)`` runs
    ``simulate`` (the server's: in a compute process); by default here, in this thread. A call
    that raises (a stopped compute process) is retried on later rounds, ``MAX_ATTEMPTS`` in
    all (counted in ``failures``), then stored as an error."""
    call = call or simulate
    failures = {} if failures is None else failures
    with db.read() as s:
        jobs = pending_jobs(s, limit=limit)
        ready = {j: reusable(s, j) for j in jobs}
    stored = 0
    for job in jobs:
        outcome = ready[job]
        if outcome is None:
            try:
                outcome = call(job)
            except Exception as exc:
                key = (job.trial_id, job.kind)
                failures[key] = failures.get(key, 0) + 1
                log.warning("sim twin of trial %d (%s) not made: %s", job.trial_id, job.kind, exc)
                if failures[key] < MAX_ATTEMPTS:
                    continue
                outcome = {"status": "error", "error": f"the twin could not run: {exc}"}
        try:
            with db.write() as s:
                stored += store(s, job, outcome) is not None
        except IntegrityError:  # stored meanwhile by another server over the same database
            continue
    return stored


class TwinRunner:
    """Polls for missing twins every ``interval_s`` on a daemon thread and makes them with
    ``call`` (None: ``simulate`` on this thread); ``start`` / ``stop`` are lifespan hooks."""

    def __init__(self, db: Database, call: Call | None, *, interval_s: float = 1.0) -> None:
        self.db = db
        self.call = call
        self.interval_s = interval_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._failures: dict[tuple[int, str], int] = {}

    def start(self) -> None:
        if self._thread is not None:
            return
        self._thread = threading.Thread(target=self._loop, name="sim-twins", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                while run_pending(self.db, call=self.call, failures=self._failures):
                    if self._stop.is_set():
                        return
            except Exception:  # a busy database, a closed engine: try again next round
                log.exception("sim twin round failed")

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)


# --- reading ---------------------------------------------------------------------------------
def twins_of(session: Session, trial_id: int) -> list[TwinRead]:
    """A trial's twins (planned first)."""
    rows = session.scalars(
        select(TrialTwin).where(TrialTwin.trial_id == trial_id).order_by(TrialTwin.id)
    )
    return [TwinRead.model_validate(r) for r in rows]


def current(twins: list[TwinRead]) -> TwinRead | None:
    """The twin that speaks for the trial: of what it executed once it ran, else of its plan."""
    by_kind: dict[str, TwinRead] = {t.kind: t for t in twins}
    return by_kind.get(EXECUTED) or by_kind.get(PLANNED)


def comparison(session: Session, experiment_id: int) -> list[TwinComparisonRead]:
    """Each hardware trial beside its current twin, with hardware objective − prediction."""
    get_experiment(session, experiment_id)
    trials = list(
        session.scalars(
            select(Trial).where(Trial.experiment_id == experiment_id).order_by(Trial.index)
        )
    )
    ids = [t.id for t in trials]
    by_trial: dict[int, list[TwinRead]] = {}
    if ids:
        for row in session.scalars(
            select(TrialTwin).where(TrialTwin.trial_id.in_(ids)).order_by(TrialTwin.id)
        ):
            by_trial.setdefault(row.trial_id, []).append(TwinRead.model_validate(row))
    out = []
    for t in trials:
        twin = current(by_trial.get(t.id, []))
        gap = None
        if t.objective is not None and twin is not None and twin.predicted_objective is not None:
            gap = float(t.objective) - float(twin.predicted_objective)
        out.append(
            TwinComparisonRead(
                trial_id=t.id,
                index=t.index,
                status=t.status,
                objective=t.objective,
                objective_sem=t.objective_sem,
                twin=twin,
                discrepancy=gap,
            )
        )
    return out


def twin_for_claim(session: Session, trial_id: int) -> TwinRead | None:
    """The twin of the schedule a hardware worker is about to run (its planned twin)."""
    row = session.scalar(
        select(TrialTwin).where(TrialTwin.trial_id == trial_id, TrialTwin.kind == PLANNED)
    )
    return None if row is None else TwinRead.model_validate(row)
