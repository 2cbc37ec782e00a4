"""The trial lifecycle: every legal status change, in one table, and the one function that
applies it (status, reason, timestamps, audit row).

    proposed ──▶ awaiting_confirmation (hardware) ──confirm──▶ queued ──claim/run──▶ running
       │                                                         │                    │
       └──────────────▶ queued (sim) ◀──requeue (lease expired)──┼────────────────────┤
                                                                 ▼                    ▼
                      completed · failed (reason) · abandoned · needs_review (a person decides)
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime
from typing import Any, Final

from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import Trial
from app.service.audit import record
from app.service.errors import IllegalTransition

PROPOSED = "proposed"
AWAITING_CONFIRMATION = "awaiting_confirmation"
QUEUED = "queued"
RUNNING = "running"
COMPLETED = "completed"
FAILED = "failed"
ABANDONED = "abandoned"
NEEDS_REVIEW = "needs_review"

STATUSES: Final = (
    PROPOSED,
    AWAITING_CONFIRMATION,
    QUEUED,
    RUNNING,
    COMPLETED,
    FAILED,
    ABANDONED,
    NEEDS_REVIEW,
)

#: status → the statuses it may move to. Nothing leaves completed, failed or abandoned.
TRANSITIONS: Final[Mapping[str, frozenset[str]]] = {
    PROPOSED: frozenset({AWAITING_CONFIRMATION, QUEUED, ABANDONED, FAILED}),
    AWAITING_CONFIRMATION: frozenset({QUEUED, ABANDONED, FAILED}),
    QUEUED: frozenset({RUNNING, COMPLETED, ABANDONED, FAILED, NEEDS_REVIEW}),
    RUNNING: frozenset({COMPLETED, FAILED, NEEDS_REVIEW, QUEUED, ABANDONED}),
    NEEDS_REVIEW: frozenset({QUEUED, AWAITING_CONFIRMATION, COMPLETED, FAILED, ABANDONED}),
    COMPLETED: frozenset(),
    FAILED: frozenset(),
    ABANDONED: frozenset(),
}

#: trials the optimiser must treat as pending (their θ is taken, their outcome unknown).
PENDING: Final = frozenset({PROPOSED, AWAITING_CONFIRMATION, QUEUED, RUNNING})
#: trials that will never run again.
TERMINAL: Final = frozenset({COMPLETED, FAILED, ABANDONED})


def can_transition(current: str, new: str) -> bool:
    """Whether the table allows ``current → new``."""
    return new in TRANSITIONS.get(current, frozenset())


def check_transition(trial: Trial, new: str, *, action: str | None = None) -> None:
    """Raise IllegalTransition (naming the current state) unless ``trial`` may go to ``new``."""
    if not can_transition(trial.status, new):
        verb = action or f"move to {new}"
        allowed = sorted(TRANSITIONS.get(trial.status, ()))
        raise IllegalTransition(
            f"cannot {verb}: trial #{trial.index} is {trial.status}"
            + (f" (from {trial.status} it can go to {', '.join(allowed)})" if allowed else ""),
            current=trial.status,
            requested=new,
        )


def transition(
    session: Session,
    trial: Trial,
    new: str,
    *,
    actor: str,
    reason: str = "",
    action: str | None = None,
    detail: dict[str, Any] | None = None,
    now: datetime | None = None,
) -> None:
    """Move ``trial`` to ``new`` (checked), stamp times, and append the audit row."""
    check_transition(trial, new, action=action)
    now = now or utcnow()
    before = trial.status
    trial.status = new
    trial.status_reason = reason
    trial.updated_at = now
    if new == RUNNING:
        trial.started_at = now
        trial.finished_at = None
    elif new in TERMINAL or new == NEEDS_REVIEW:
        trial.finished_at = now
    elif new == QUEUED:
        trial.finished_at = None
    record(
        session,
        actor=actor,
        action=action or f"trial.{new}",
        entity="trial",
        entity_id=trial.id,
        experiment_id=trial.experiment_id,
        trial_id=trial.id,
        before=before,
        after=new,
        detail={"reason": reason, **(detail or {})} if reason or detail else None,
        now=now,
    )
