"""Drift checks: an experiment's reference schedule and its drift chart."""

from __future__ import annotations

from fastapi import APIRouter

from app.api.deps import DbDep, ExperimentId, Operator, Reader, ReadSession
from app.service import drift
from app.service.schemas import DriftRead, ReferenceIn

router = APIRouter(prefix="/experiments", tags=["experiments"])


@router.get("/{experiment_id}/drift")
def get_drift(experiment_id: ExperimentId, session: ReadSession, _: Reader) -> DriftRead:
    """The reference's scores over time, the band from the first m, and the warning when the
    latest one is beyond it."""
    return drift.drift_view(session, experiment_id)


@router.put("/{experiment_id}/reference")
def set_reference(
    experiment_id: ExperimentId, body: ReferenceIn, db: DbDep, actor: Operator
) -> DriftRead:
    """Schedule a reference θ (a chosen trial's, or the incumbent's) every k hardware trials
    (k ≥ 2); hardware experiments only."""
    with db.write() as session:
        return drift.set_reference(session, experiment_id, body, actor=actor)


@router.delete("/{experiment_id}/reference")
def stop_reference(experiment_id: ExperimentId, db: DbDep, actor: Operator) -> DriftRead:
    """Stop scheduling reference trials (those made stay, with their scores)."""
    with db.write() as session:
        return drift.set_reference(session, experiment_id, None, actor=actor)
