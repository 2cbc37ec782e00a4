"""Workers: claim trials under a lease, heartbeat, report results."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import Response

from app.api.deps import DbDep, SettingsDep, TrialId, WorkerOrOperator, json_response
from app.service import leases
from app.service.artifacts import decode_npz_b64
from app.service.schemas import ClaimIn, ClaimRead, LeaseRead, ResultIn, ResultRead

router = APIRouter(tags=["workers"])


@router.post("/workers/claim", response_model=list[ClaimRead])
def claim(body: ClaimIn, db: DbDep, settings: SettingsDep, actor: WorkerOrOperator) -> Response:
    """Claim up to max_trials queued trials of a target, each under a lease."""
    with db.write() as session:
        claims = leases.claim(
            session,
            body,
            actor=actor,
            lease_seconds=settings.lease_seconds,
            max_attempts=settings.max_attempts,
            ceilings=settings.robot.ceilings(),
        )
        return json_response(claims)


@router.post("/leases/{lease_id}/heartbeat")
def heartbeat(
    lease_id: str, db: DbDep, settings: SettingsDep, actor: WorkerOrOperator
) -> LeaseRead:
    """Keep a lease alive for another lease_seconds."""
    with db.write() as session:
        return leases.heartbeat(
            session,
            lease_id,
            actor=actor,
            lease_seconds=settings.lease_seconds,
            max_attempts=settings.max_attempts,
        )


@router.post("/trials/{trial_id}/result", response_model=ResultRead)
def result(
    trial_id: TrialId,
    body: ResultIn,
    db: DbDep,
    settings: SettingsDep,
    actor: WorkerOrOperator,
) -> dict[str, Any]:
    """Report what was executed and measured for a leased trial (idempotent per lease)."""
    raw = None
    if body.trajectory_npz_b64 is not None:  # unpacked and checked before taking the lock
        raw = decode_npz_b64(body.trajectory_npz_b64, max_bytes=settings.max_body_bytes)
    with db.write() as session:
        return leases.report_result(
            session,
            trial_id,
            body,
            actor=actor,
            artifacts_dir=settings.artifacts_dir,
            max_attempts=settings.max_attempts,
            trajectory=raw,
        )
