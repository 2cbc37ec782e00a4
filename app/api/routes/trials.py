"""Trials: read, measure, fail, abandon, resolve, confirm, run, preview, trajectory."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Header
from fastapi.responses import FileResponse, Response

from app.api.deps import (
    DbDep,
    MeasurementId,
    Operator,
    PreviewsDep,
    Reader,
    ReadSession,
    SettingsDep,
    TrialId,
    json_response,
)
from app.service import artifacts, measurements, runs, trials
from app.service.schemas import (
    ConfirmIn,
    MeasurementReceipt,
    MeasurementsIn,
    PreviewJobRead,
    ReasonIn,
    ResolveIn,
    SupersedeIn,
    TrialDetail,
    TrialRead,
    WithdrawIn,
)

router = APIRouter(tags=["trials"])


@router.get("/trials/{trial_id}", response_model=TrialDetail)
def get_trial(trial_id: TrialId, session: ReadSession, _: Reader) -> Response:
    """A trial with its raw measurements and its audit trail."""
    return json_response(trials.read_trial(session, trial_id))


@router.post("/trials/{trial_id}/measurements", status_code=201, response_model=MeasurementReceipt)
def add_measurements(
    trial_id: TrialId,
    body: MeasurementsIn,
    db: DbDep,
    actor: Operator,
    idempotency_key: str | None = Header(None, alias="Idempotency-Key"),
) -> Response:
    """Record raw repeats (value, unit, note); the objective is their mean ± SEM.

    Replies with the repeats stored and the trial's new objective (the whole trial, with
    every repeat and its audit trail, is ``GET /trials/{id}``). A replayed post (same key,
    same body) is a 409 ``duplicate_request`` carrying the first post's ``receipt``.
    """
    with db.write() as session:
        receipt = measurements.add_measurements(
            session, trial_id, body, idempotency_key=idempotency_key, actor=actor
        )
    return json_response(receipt, status_code=201)


@router.post("/measurements/{measurement_id}/withdraw", response_model=MeasurementReceipt)
def withdraw_measurement(
    measurement_id: MeasurementId, body: WithdrawIn, db: DbDep, actor: Operator
) -> MeasurementReceipt:
    """Withdraw a repeat with a reason: kept (and audited), no longer in the objective."""
    with db.write() as session:
        return measurements.withdraw_measurement(session, measurement_id, body.reason, actor=actor)


@router.post(
    "/measurements/{measurement_id}/supersede", status_code=201, response_model=MeasurementReceipt
)
def supersede_measurement(
    measurement_id: MeasurementId, body: SupersedeIn, db: DbDep, actor: Operator
) -> Response:
    """Correct a repeat: the old value is kept, withdrawn with the reason; the new one counts."""
    with db.write() as session:
        receipt = measurements.supersede_measurement(session, measurement_id, body, actor=actor)
    return json_response(receipt, status_code=201)


@router.post("/trials/{trial_id}/fail")
def fail(trial_id: TrialId, body: ReasonIn, db: DbDep, actor: Operator) -> TrialRead:
    """Mark a trial failed, with a reason (aborts it if running)."""
    with db.write() as session:
        return trials.fail(session, trial_id, body.reason, actor=actor)


@router.post("/trials/{trial_id}/abandon")
def abandon(trial_id: TrialId, body: ReasonIn, db: DbDep, actor: Operator) -> TrialRead:
    """Abandon a trial: it never runs and is never suggested again."""
    with db.write() as session:
        return trials.abandon(session, trial_id, body.reason, actor=actor)


@router.post("/trials/{trial_id}/resolve")
def resolve(trial_id: TrialId, body: ResolveIn, db: DbDep, actor: Operator) -> TrialRead:
    """Decide a needs_review trial: requeue, fail, complete or abandon."""
    with db.write() as session:
        return trials.resolve(session, trial_id, body, actor=actor)


@router.post("/trials/{trial_id}/confirm")
def confirm(
    trial_id: TrialId, body: ConfirmIn, db: DbDep, settings: SettingsDep, actor: Operator
) -> TrialRead:
    """Confirm a hardware trial's exact schedule (by its hash) so a worker may run it.

    Refused unless this operator previewed exactly this schedule (``POST .../preview``)."""
    with db.write() as session:
        return trials.confirm(
            session, trial_id, body.schedule_hash, actor=actor, ceilings=settings.robot.ceilings()
        )


@router.post("/trials/{trial_id}/run")
def run(trial_id: TrialId, db: DbDep, settings: SettingsDep, actor: Operator) -> TrialRead:
    """Simulate a queued sim trial in the service and record its result."""
    return runs.run_trial(
        db,
        trial_id,
        actor=actor,
        artifacts_dir=settings.artifacts_dir,
        lease_seconds=settings.lease_seconds,
    )


@router.post("/trials/{trial_id}/preview", status_code=202)
def preview(
    trial_id: TrialId, db: DbDep, previews: PreviewsDep, settings: SettingsDep, actor: Operator
) -> PreviewJobRead:
    """Start a sim rollout of exactly this trial's schedule; poll /api/previews/{job_id}.

    Once done it is recorded as this operator's preview of that schedule (what confirming
    a hardware trial requires)."""
    return previews.submit(db, trial_id, actor=actor, ceilings=settings.robot.ceilings())


@router.get("/previews/{job_id}")
def get_preview(job_id: str, previews: PreviewsDep, _: Reader) -> PreviewJobRead:
    """A preview's status and progress; when done its tip speed, bend-limit hits, trajectory."""
    return previews.get(job_id)


@router.get(
    "/trials/{trial_id}/trajectory",
    response_model=None,
    responses={
        200: {
            "description": "JSON: each array as nested lists; npz: the file, streamed",
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            },
        }
    },
)
def trajectory(
    trial_id: TrialId,
    session: ReadSession,
    settings: SettingsDep,
    _: Reader,
    format: Literal["json", "npz"] = "json",
) -> FileResponse | dict:
    """The trial's recorded trajectory: arrays as JSON lists, or the .npz file."""
    path = artifacts.trajectory_path(session, settings.artifacts_dir, trial_id)
    if format == "npz":
        return FileResponse(path, media_type="application/octet-stream", filename=path.name)
    return artifacts.npz_to_json(path)
