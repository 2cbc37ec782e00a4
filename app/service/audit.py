"""The append-only audit log: one row per state change, confirmation, override or abort."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import AuditLog


def record(
    session: Session,
    *,
    actor: str,
    action: str,
    entity: str,
    entity_id: int | str,
    experiment_id: int | None = None,
    trial_id: int | None = None,
    before: str | None = None,
    after: str | None = None,
    detail: dict[str, Any] | None = None,
    now: datetime | None = None,
) -> AuditLog:
    """Append one audit row (flushed with the caller's transaction, never on its own)."""
    row = AuditLog(
        at=now or utcnow(),
        actor=actor,
        action=action,
        entity=entity,
        entity_id=str(entity_id),
        experiment_id=experiment_id,
        trial_id=trial_id,
        before=before,
        after=after,
        detail=detail,
    )
    session.add(row)
    return row
