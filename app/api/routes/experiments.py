"""Experiments: create, list, read, change; suggest, attach, export, import, model, version."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any, Literal, TypeVar

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import PlainTextResponse

from app.api.deps import (
    ComputeDep,
    DbDep,
    ExperimentId,
    Operator,
    Reader,
    ReadSession,
    SettingsDep,
    json_response,
)
from app.service import bundle, data, experiments, trials
from app.service import compute as compute_jobs
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
T = TypeVar("T")


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
def get_experiment(experiment_id: ExperimentId, session: ReadSession, _: Reader) -> ExperimentRead:
    """One experiment."""
    return experiments.read_experiment(session, experiment_id)


@router.patch("/{experiment_id}")
def patch_experiment(
    experiment_id: ExperimentId, body: ExperimentPatch, db: DbDep, actor: Operator
) -> ExperimentRead:
    """Change an experiment's status, notes or budget."""
    with db.write() as session:
        return experiments.patch_experiment(session, experiment_id, body, actor=actor)


@router.get("/{experiment_id}/trials")
def list_trials(
    experiment_id: ExperimentId,
    session: ReadSession,
    _: Reader,
    status: str | None = Query(None, description="only trials in this status"),
) -> list[TrialRead]:
    """An experiment's trials, in index order."""
    return trials.list_trials(session, experiment_id, status=status)


async def _while_connected(request: Request, work: Callable[[threading.Event], T]) -> T:
    """``work(cancelled)`` in the threadpool; ``cancelled`` is set if the client leaves."""
    cancelled = threading.Event()
    task = asyncio.ensure_future(run_in_threadpool(work, cancelled))
    try:
        while True:
            done, _ = await asyncio.wait({task}, timeout=0.25)
            if done:
                return task.result()
            if await request.is_disconnected():
                cancelled.set()
    finally:
        if not task.done():
            cancelled.set()


@router.post("/{experiment_id}/suggest", status_code=201, response_model=list[TrialRead])
async def suggest(
    experiment_id: ExperimentId,
    body: SuggestIn,
    db: DbDep,
    compute: ComputeDep,
    settings: SettingsDep,
    actor: Operator,
    request: Request,
) -> Response:
    """Ask the optimiser (rebuilt from the database) for n new trials.

    A hardware experiment with a drift check gets its due reference trials too, each before
    the suggestion it precedes (``source = "reference"``): the reply may hold more than n.

    The optimiser runs in a compute process within ``HANDFUL_SUGGEST_TIMEOUT_S`` (past it:
    503 ``compute_timeout``, nothing stored) and is stopped if the client leaves. The
    ``Server-Timing`` header gives the optimiser's share (``optimizer``) and the whole
    suggestion (``total``) in ms, so clients can tell the service's overhead from the GP's.
    """

    def work(cancelled: threading.Event) -> tuple[list[TrialRead], dict[str, float]]:
        timings: dict[str, float] = {}

        def asker(inputs: Any, n: int) -> Any:
            return compute.call(
                compute_jobs.suggest_job,
                inputs,
                n,
                shard=experiment_id,
                cancelled=cancelled,
                in_thread=compute_jobs.inline(inputs),
            )

        out = trials.suggest(
            db,
            experiment_id,
            body.n,
            actor=actor,
            timings=timings,
            asker=asker,
            ceilings=settings.robot.ceilings(),
        )
        return out, timings

    t0 = time.perf_counter()
    out, timings = await _while_connected(request, work)
    total_ms = (time.perf_counter() - t0) * 1e3
    response = json_response(out, status_code=201)
    response.headers["Server-Timing"] = (
        f"optimizer;dur={timings.get('optimizer_s', 0.0) * 1e3:.3f}, total;dur={total_ms:.3f}"
    )
    return response


@router.post("/{experiment_id}/trials", status_code=201)
def attach_trial(
    experiment_id: ExperimentId, body: AttachIn, db: DbDep, settings: SettingsDep, actor: Operator
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


@router.get(
    "/{experiment_id}/export",
    response_model=None,
    responses={
        200: {
            "description": "JSON: trials and measurements; bundle: everything (trajectories "
            "and audit log too, what `handful import` reads); CSV: one row per trial",
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "text/csv": {"schema": {"type": "string"}},
            },
        }
    },
)
def export(
    experiment_id: ExperimentId,
    session: ReadSession,
    _: Reader,
    settings: SettingsDep,
    format: Literal["csv", "json", "bundle"] = "json",
) -> PlainTextResponse | dict:
    """The experiment's trials (CSV: one row per trial, who and raw repeats included), its
    trials and measurements (JSON), or everything, trajectories and audit log too (bundle)."""
    if format == "bundle":
        return bundle.export_bundle(session, experiment_id, settings.artifacts_dir)
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
    experiment_id: ExperimentId, body: ImportIn, db: DbDep, actor: Operator
) -> list[TrialRead]:
    """Import past observations (θ, objective) as completed trials."""
    with db.write() as session:
        return data.import_observations(session, experiment_id, body, actor=actor)


@router.get("/{experiment_id}/model", response_model=ModelRead)
async def model(
    experiment_id: ExperimentId, db: DbDep, compute: ComputeDep, _: Reader, request: Request
) -> Response:
    """The GP's lengthscales, the incumbent, and posterior slices through it.

    Reuses the fit of the experiment's last suggestion on the same observations
    (``X-Model-Cache: hit``); else fits it once in a compute process (``miss``), bounded
    like a suggestion."""
    cache = {"hit": False}

    def work(cancelled: threading.Event) -> ModelRead:
        def viewer(inputs: Any, incumbent: list[float], n_points: int) -> dict[str, Any]:
            view, cache["hit"] = compute.call(
                compute_jobs.model_job,
                inputs,
                incumbent,
                n_points,
                shard=experiment_id,
                cancelled=cancelled,
                what="the GP fit",
                in_thread=compute_jobs.inline(inputs),
            )
            return view

        with db.read() as session:
            return data.model_insight(session, experiment_id, viewer=viewer)

    out = await _while_connected(request, work)
    response = json_response(out)
    response.headers["X-Model-Cache"] = "hit" if cache["hit"] else "miss"
    return response


@router.get("/{experiment_id}/audit")
def audit(
    experiment_id: ExperimentId,
    session: ReadSession,
    _: Reader,
    limit: int = Query(500, ge=1, le=10_000),
) -> list[AuditRead]:
    """The experiment's audit log, newest first."""
    return experiments.audit_log(session, experiment_id, limit=limit)


@router.get("/{experiment_id}/version")
def version(experiment_id: ExperimentId, session: ReadSession, _: Reader) -> VersionRead:
    """A counter that changes whenever anything in the experiment changes (cheap to poll)."""
    return VersionRead(
        experiment_id=experiment_id,
        version=experiments.experiment_version(session, experiment_id),
    )
