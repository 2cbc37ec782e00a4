"""The append-only audit log: one row per state change, confirmation, override or abort."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Any

from sqlalchemy import insert
from sqlalchemy.engine import Connection
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import AuditLog

# Built once: constructing a statement costs more than running it on SQLite.
_INSERT = insert(AuditLog.__table__)


def json_safe(value: Any) -> Any:
    """``value`` with NaN and ±inf (which JSON cannot hold) as null, recursively."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def record(
    session: Session | Connection,
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
) -> None:
    """Append one audit row in the caller's transaction (a plain INSERT, committed with it).

    Rows are written when recorded, so their ids follow the order of the calls. ``detail``
    is stored as strict JSON (NaN and ±inf become null).
    ``session``: the caller's Session, or the Connection it holds.
    """
    conn = session.connection() if isinstance(session, Session) else session
    conn.execute(
        _INSERT,
        {
            "at": now or utcnow(),
            "actor": actor,
            "action": action,
            "entity": entity,
            "entity_id": str(entity_id),
            "experiment_id": experiment_id,
            "trial_id": trial_id,
            "before": before,
            "after": after,
            "detail": None if detail is None else json_safe(detail),
        },
    )
