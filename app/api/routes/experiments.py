"""Experiments: create, list, read, change; suggest, attach, export, import, model, version."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Literal

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import PlainTextResponse, StreamingResponse

from app.api.deps import DbDep, Operator, Reader, ReadSession, SettingsDep
from app.service import data, experiments, trials
from app.service.errors import NotFound
from app.service.schemas import (
    AttachIn,
    AuditRead,
    ExperimentCreate,
    ExperimentPatch,
    ExperimentRead,
    ImportIn,
    ModelRead,
    SuggestIn,
    TrialRead,
    VersionRead,
)

router = APIRouter(prefix="/experiments", tags=["experiments"])


@router.post("", status_code=201)
def create_experiment(
    body: ExperimentCreate, db: DbDep, settings: SettingsDep, actor: Operator
) -> ExperimentRead:
    """Create an experiment (task, target, policy P/H/release, limits, optimiser, budget).

    A hardware experiment's limits must lie within the robot's ceilings (server settings)."""
    with db.write() as session:
        exp = experiments.create_experiment(
            session, body, actor=actor, ceilings=settings.robot.ceilings()
        )
        return experiments.read_experiment(session, exp.id)


@router.get("")
def list_experiments(session: ReadSession, _: Reader) -> list[ExperimentRead]:
    """All experiments, newest first, with trial counts and best objective."""
    return experiments.list_experiments(session)


@router.get("/{experiment_id}")
def get_experiment(experiment_id: int, session: ReadSession, _: Reader) -> ExperimentRead:
    """One experiment."""
    return experiments.read_experiment(session, experiment_id)


@router.patch("/{experiment_id}")
def patch_experiment(
    experiment_id: int, body: ExperimentPatch, db: DbDep, actor: Operator
) -> ExperimentRead:
    """Change an experiment's status, notes or budget."""
    with db.write() as session:
        return experiments.patch_experiment(session, experiment_id, body, actor=actor)


@router.get("/{experiment_id}/trials")
def list_trials(
    experiment_id: int,
    session: ReadSession,
    _: Reader,
    status: str | None = Query(None, description="only trials in this status"),
) -> list[TrialRead]:
    """An experiment's trials, in index order."""
    return trials.list_trials(session, experiment_id, status=status)


@router.post("/{experiment_id}/suggest", status_code=201)
def suggest(
    experiment_id: int,
    body: SuggestIn,
    db: DbDep,
    settings: SettingsDep,
    actor: Operator,
    response: Response,
) -> list[TrialRead]:
    """Ask the optimiser (rebuilt from the database) for n new trials.

    The ``Server-Timing`` header gives the optimiser's share (``optimizer``) and the whole
    suggestion (``total``) in ms, so clients can tell the service's overhead from the GP's.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    out = trials.suggest(
        db,
        experiment_id,
        body.n,
        actor=actor,
        timings=timings,
        ceilings=settings.robot.ceilings(),
    )
    total_ms = (time.perf_counter() - t0) * 1e3
    response.headers["Server-Timing"] = (
        f"optimizer;dur={timings.get('optimizer_s', 0.0) * 1e3:.3f}, total;dur={total_ms:.3f}"
    )
    return out


@router.post("/{experiment_id}/trials", status_code=201)
def attach_trial(
    experiment_id: int, body: AttachIn, db: DbDep, settings: SettingsDep, actor: Operator
) -> TrialRead:
    """Add a trial with a θ the operator chose."""
    with db.write() as session:
        return trials.attach(
            session,
            experiment_id,
            body.theta,
            note=body.note,
            actor=actor,
            ceilings=settings.robot.ceilings(),
        )


@router.get("/{experiment_id}/export", response_model=None)
def export(
    experiment_id: int,
    session: ReadSession,
    _: Reader,
    format: Literal["csv", "json"] = "json",
) -> PlainTextResponse | dict:
    """The experiment's trials (CSV: one row per trial) or everything (JSON)."""
    if format == "csv":
        text = data.export_csv(session, experiment_id)
        return PlainTextResponse(
            text,
            media_type="text/csv",
            headers={
                "Content-Disposition": f'attachment; filename="experiment_{experiment_id}.csv"'
            },
        )
    return data.export_json(session, experiment_id)


@router.post("/{experiment_id}/import", status_code=201)
def import_observations(
    experiment_id: int, body: ImportIn, db: DbDep, actor: Operator
) -> list[TrialRead]:
    """Import past observations (θ, objective) as completed trials."""
    with db.write() as session:
        return data.import_observations(session, experiment_id, body, actor=actor)


@router.get("/{experiment_id}/model")
def model(experiment_id: int, session: ReadSession, _: Reader) -> ModelRead:
    """The GP's lengthscales, the incumbent, and posterior slices through it."""
    return data.model_insight(session, experiment_id)


@router.get("/{experiment_id}/audit")
def audit(
    experiment_id: int, session: ReadSession, _: Reader, limit: int = Query(500, ge=1, le=10_000)
) -> list[AuditRead]:
    """The experiment's audit log, newest first."""
    return experiments.audit_log(session, experiment_id, limit=limit)


@router.get("/{experiment_id}/version")
def version(experiment_id: int, session: ReadSession, _: Reader) -> VersionRead:
    """A counter that changes whenever anything in the experiment changes (cheap to poll)."""
    return VersionRead(
        experiment_id=experiment_id,
        version=experiments.experiment_version(session, experiment_id),
    )


@router.get("/{experiment_id}/events")
async def events(experiment_id: int, request: Request, db: DbDep, _: Reader) -> StreamingResponse:
    """Server-sent events: ``data: {"version": n}`` each time the experiment changes."""

    def current() -> int:
        with db.read() as s:
            return experiments.experiment_version(s, experiment_id)

    first = await run_in_threadpool(current)  # NotFound before the stream starts

    async def stream() -> AsyncIterator[str]:
        last = first
        yield f"data: {json.dumps({'version': last})}\n\n"
        idle = 0.0
        while not await request.is_disconnected():
            await asyncio.sleep(0.5)
            idle += 0.5
            try:
                v = await run_in_threadpool(current)
            except NotFound:
                return
            if v != last:
                last, idle = v, 0.0
                yield f"data: {json.dumps({'version': v})}\n\n"
            elif idle >= 15.0:
                idle = 0.0
                yield ": keep-alive\n\n"

    return StreamingResponse(stream(), media_type="text/event-stream")
