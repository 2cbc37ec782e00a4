"""A hardware experiment's sim prior (link, unlink, start one) and its trials' sim twins."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from app.api.deps import (
    ComputeDep,
    DbDep,
    ExperimentId,
    Operator,
    Reader,
    ReadSession,
    SettingsDep,
    TrialId,
)
from app.service import compute as compute_jobs
from app.service import sim_prior, trials, twins
from app.service.schemas import (
    ExperimentRead,
    SimPriorLinkIn,
    SimPriorRead,
    SimPriorStarted,
    SimPriorStartIn,
    TrialRead,
    TwinComparisonRead,
    TwinRead,
)

router = APIRouter(tags=["sim prior and twins"])


@router.get("/experiments/{experiment_id}/sim-prior")
def read_sim_prior(experiment_id: ExperimentId, session: ReadSession, _: Reader) -> SimPriorRead:
    """The linked sim experiment, how many of its trials are scored (the prior's data) and
    still to run, and the preset the sim twins run with."""
    return sim_prior.read_sim_prior(session, experiment_id)


@router.put("/experiments/{experiment_id}/sim-prior")
def link_sim_prior(
    experiment_id: ExperimentId, body: SimPriorLinkIn, db: DbDep, actor: Operator
) -> ExperimentRead:
    """Link a hardware experiment to a sim experiment of the same task, policy (P, H, release
    step) and command hold: its optimiser then also learns from the sim trials (which never
    count against its budget). 422 saying what differs otherwise."""
    with db.write() as session:
        return sim_prior.link(session, experiment_id, body.sim_experiment_id, actor=actor)


@router.delete("/experiments/{experiment_id}/sim-prior")
def unlink_sim_prior(experiment_id: ExperimentId, db: DbDep, actor: Operator) -> ExperimentRead:
    """Drop the link: later suggestions learn from the hardware trials only."""
    with db.write() as session:
        return sim_prior.unlink(session, experiment_id, actor=actor)


@router.post("/experiments/{experiment_id}/sim-prior/start", status_code=201)
def start_sim_prior(
    experiment_id: ExperimentId,
    body: SimPriorStartIn,
    db: DbDep,
    compute: ComputeDep,
    settings: SettingsDep,
    actor: Operator,
) -> SimPriorStarted:
    """Start a sim prior: a new sim experiment with this one's task, policy, hold, method and
    seed (the paper-matching preset unless told), linked, with ``n_trials`` sim trials queued
    for the sim workers."""

    def suggest(sim_id: int, n: int) -> list[TrialRead]:
        def asker(inputs: Any, k: int) -> Any:
            return compute.call(
                compute_jobs.suggest_job,
                inputs,
                k,
                shard=sim_id,
                in_thread=compute_jobs.inline(inputs),
            )

        return trials.suggest(
            db, sim_id, n, actor=actor, asker=asker, ceilings=settings.robot.ceilings()
        )

    return sim_prior.start(db, experiment_id, body, actor=actor, suggest=suggest)


@router.get("/experiments/{experiment_id}/twins")
def experiment_twins(
    experiment_id: ExperimentId, session: ReadSession, _: Reader
) -> list[TwinComparisonRead]:
    """Each trial beside its sim twin (of what it executed, else of its plan): the hardware
    objective, the twin's prediction and their difference."""
    return twins.comparison(session, experiment_id)


@router.get("/trials/{trial_id}/twins")
def trial_twins(trial_id: TrialId, session: ReadSession, _: Reader) -> list[TwinRead]:
    """A hardware trial's sim twins (planned: before it runs; executed: what the robot ran)."""
    trials.get_trial(session, trial_id)
    return twins.twins_of(session, trial_id)
