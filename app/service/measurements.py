"""Measurements: every raw repeat kept; a trial's objective is their mean, with its SEM."""

from __future__ import annotations

import hashlib
import json
import math
from collections import namedtuple
from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

from sqlalchemy import bindparam, exists, insert, select, update
from sqlalchemy import inspect as sa_inspect
from sqlalchemy.engine import Connection
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session
from sqlalchemy.orm.attributes import set_committed_value

from app.db.base import utcnow
from app.db.models import Experiment, IdempotencyKey, Lease, Measurement, Trial
from app.service import lifecycle as lc
from app.service.audit import record
from app.service.auth import Actor
from app.service.drift import REFERENCE, check_drift
from app.service.errors import (
    Conflict,
    DuplicateRequest,
    IllegalTransition,
    InvalidInput,
    NotFound,
)
from app.service.experiments import touch_id
from app.service.schemas import (
    MeasurementRead,
    MeasurementReceipt,
    MeasurementsIn,
    SupersedeIn,
    objective_sources_of,
    sources_list,
)

#: plausible range of one measurement, per unit (anything outside is a typo or a unit mix-up)
UNIT_RANGE: dict[str, tuple[float, float]] = {
    "m": (0.0, 1000.0),  # a distance: never negative
    "m/s": (0.0, 100.0),  # a speed: the real tip tops out near 5 m/s
    "N": (0.0, 100_000.0),  # a force on the plate
    "score": (-1e6, 1e6),  # a task objective in its own units (hammer can go negative)
}
MEASURABLE = frozenset({lc.QUEUED, lc.RUNNING, lc.COMPLETED, lc.NEEDS_REVIEW})


def objective_from_repeats(values: Sequence[float]) -> tuple[float, float | None]:
    """Mean of the repeats, and its standard error std/√n (ddof=1) when n ≥ 2, else None."""
    v = [float(x) for x in values]
    n = len(v)
    if n == 0:
        raise ValueError("no repeats")
    mean = math.fsum(v) / n
    if n < 2:
        return mean, None
    variance = math.fsum((x - mean) ** 2 for x in v) / (n - 1)
    return mean, math.sqrt(variance / n)


def check_value(value: float, unit: str, expected_unit: str, *, what: str = "value") -> None:
    """InvalidInput unless ``value`` is finite, in the experiment's unit and plausible."""
    if unit != expected_unit:
        raise InvalidInput(
            f"{what}: unit {unit!r} is not this experiment's objective unit {expected_unit!r}"
        )
    if not math.isfinite(value):
        raise InvalidInput(f"{what} {value!r} is not a finite number")
    lo, hi = UNIT_RANGE[unit]
    if not lo <= value <= hi:
        if value < 0 and lo == 0.0:
            kind = "distance" if unit == "m" else "speed" if unit == "m/s" else "force"
            raise InvalidInput(f"{what} {value!r} {unit}: a {kind} cannot be negative")
        raise InvalidInput(f"{what} {value!r} {unit} is outside the plausible [{lo:g}, {hi:g}]")


# Built once: a measurement post is a handful of Core statements on the session's connection
# (no ORM load, no flush unless the status changes); ``Database.write`` commits it.
_MEASUREMENTS = Measurement.__table__
_TRIALS = Trial.__table__
_VALUES_OF = (
    select(_MEASUREMENTS.c.value, _MEASUREMENTS.c.source)
    .where(
        _MEASUREMENTS.c.trial_id == bindparam("trial_id"),
        _MEASUREMENTS.c.withdrawn_at.is_(None),
    )
    .order_by(_MEASUREMENTS.c.id)
)
_INSERT_REPEAT = insert(_MEASUREMENTS).returning(_MEASUREMENTS.c.id)
_SET_OBJECTIVE = (
    update(_TRIALS)
    .where(_TRIALS.c.id == bindparam("trial_id"))
    .values(
        objective=bindparam("new_objective"),
        objective_sem=bindparam("new_objective_sem"),
        n_measurements=bindparam("new_n_measurements"),
        updated_at=bindparam("new_updated_at"),
    )
)
_KEYS = IdempotencyKey.__table__
_KEY_SEEN = select(_KEYS.c.request_sha256, _KEYS.c.summary, _KEYS.c.receipt).where(
    _KEYS.c.scope == bindparam("scope"), _KEYS.c.key == bindparam("key")
)
_INSERT_KEY = insert(_KEYS)
_LEASES = Lease.__table__
#: what a post needs of its trial (status, objective, the experiment's unit, a worker's
#: lease) and whether its Idempotency-Key was seen: one round trip
_TRIAL_TO_MEASURE = (
    select(
        _TRIALS.c.id,
        _TRIALS.c.experiment_id,
        _TRIALS.c.status,
        _TRIALS.c.objective,
        Experiment.__table__.c.objective_unit,
        exists()
        .where(_LEASES.c.trial_id == _TRIALS.c.id, _LEASES.c.status == "active")
        .label("leased"),
        exists()
        .where(_KEYS.c.scope == bindparam("scope"), _KEYS.c.key == bindparam("key"))
        .label("key_seen"),
        Experiment.__table__.c.objective_sources,
        Experiment.__table__.c.task,
        Experiment.__table__.c.target,
        _TRIALS.c.index,
        _TRIALS.c.source,
    )
    .join(Experiment.__table__, Experiment.__table__.c.id == _TRIALS.c.experiment_id)
    .where(_TRIALS.c.id == bindparam("trial_id"))
    .with_for_update(of=_TRIALS)  # PostgreSQL locks the row; SQLite holds the write lock
)
_TrialToMeasure = namedtuple(
    "_TrialToMeasure",
    "id experiment_id status objective objective_unit leased key_seen objective_sources task "
    "target index source",
)
_COUNTED = ("objective", "objective_sem", "n_measurements", "updated_at")
_TRIAL_KEY = sa_inspect(Trial).identity_key_from_primary_key


def _sources_of(session: Session, experiment_id: int) -> list[str]:
    exp = session.get(Experiment, experiment_id)
    assert exp is not None
    return objective_sources_of(exp)


def _refresh_objective(
    session: Session, db: Connection, trial: Any, sources: Sequence[str], now: Any
) -> tuple[float | None, float | None]:
    """Recompute the trial's objective, SEM and count from its repeats that count (not
    withdrawn, from one of ``sources``), in SQL and on ``trial``; return (objective, SEM)."""
    counted_values = [
        float(v)
        for v, src in db.execute(_VALUES_OF, {"trial_id": trial.id}).fetchall()
        if src in sources
    ]
    objective: float | None
    sem: float | None
    if counted_values:
        objective, sem = objective_from_repeats(counted_values)
    else:
        objective, sem = None, None
    counted = dict(zip(_COUNTED, (objective, sem, len(counted_values), now), strict=True))
    db.execute(
        _SET_OBJECTIVE, {"trial_id": trial.id, **{f"new_{k}": v for k, v in counted.items()}}
    )
    state = sa_inspect(trial, raiseerr=False)
    for name, value in counted.items():
        if state is not None:
            set_committed_value(trial, name, value)
        else:
            setattr(trial, name, value)
    if state is not None and "measurements" in state.dict:  # a loaded collection is now stale
        session.expire(trial, ["measurements"])
    if getattr(trial, "source", None) == REFERENCE:  # a drift check's score: judge it
        check_drift(session, trial.experiment_id, now=now)
    return objective, sem


def store_measurement(
    session: Session,
    trial: Any,
    values: Sequence[tuple[float, str, str] | tuple[float, str, str, str]],
    *,
    actor: Actor,
    source: str,
    objective_sources: Sequence[str] | None = None,
    supersedes_id: int | None = None,
) -> list[MeasurementRead]:
    """Append raw repeats (value, unit, note[, source]) to ``trial`` and refresh its
    objective, SEM and count from the repeats that count (not withdrawn, from one of the
    experiment's ``objective_sources``), in SQL and on ``trial``: a flushed ORM Trial (left
    in step with its row, nothing to flush) or any object with ``id``, ``experiment_id`` and
    ``objective`` attributes (which get the new values). ``source``: tape | tracker | sim |
    imported, unless a repeat names its own.

    Returns the repeats stored, in order.
    """
    now = utcnow()
    db = session.connection()
    if objective_sources is None:
        objective_sources = _sources_of(session, trial.experiment_id)
    stored = []
    for v, u, note, *own in values:
        row = {
            "trial_id": trial.id,
            "value": float(v),
            "unit": u,
            "note": note,
            "source": own[0] if own else source,
            "created_by": actor.username,
            "created_at": now,
            "supersedes_id": supersedes_id,
        }
        inserted = db.execute(_INSERT_REPEAT, row).fetchone()
        assert inserted is not None  # INSERT ... RETURNING gives the row
        (repeat_id,) = inserted
        stored.append(MeasurementRead(id=repeat_id, **row))
    before = trial.objective
    objective, _ = _refresh_objective(session, db, trial, objective_sources, now)
    record(
        db,
        actor=actor.username,
        action="trial.measure",
        entity="trial",
        entity_id=trial.id,
        experiment_id=trial.experiment_id,
        trial_id=trial.id,
        before=None if before is None else repr(before),
        after=None if objective is None else repr(objective),
        detail={
            "sources": sorted({m.source for m in stored}),
            "values": [float(v[0]) for v in values],
        },
        now=now,
    )
    return stored


def _correctable(session: Session, measurement_id: int) -> tuple[Measurement, Trial]:
    m = session.get(Measurement, measurement_id, with_for_update=True)
    if m is None:
        raise NotFound(f"measurement {measurement_id} not found")
    trial = session.get(Trial, m.trial_id, with_for_update=True)
    assert trial is not None
    if m.withdrawn_at is not None:
        raise Conflict(
            f"this repeat ({m.value:g} {m.unit}) of trial #{trial.index} was already withdrawn "
            f"by {m.withdrawn_by}: {m.withdrawn_reason}"
        )
    return m, trial


def _withdraw(m: Measurement, reason: str, actor: Actor, now: Any) -> None:
    m.withdrawn_at = now
    m.withdrawn_by = actor.username
    m.withdrawn_reason = reason


def withdraw_measurement(
    session: Session, measurement_id: int, reason: str, *, actor: Actor
) -> MeasurementReceipt:
    """Withdraw a repeat (kept, no longer counted), recompute the objective (flushed;
    the caller's ``Database.write`` commits)."""
    m, trial = _correctable(session, measurement_id)
    now = utcnow()
    before = trial.objective
    _withdraw(m, reason, actor, now)
    session.flush()
    objective, _ = _refresh_objective(
        session, session.connection(), trial, objective_sources_of(trial.experiment), now
    )
    record(
        session,
        actor=actor.username,
        action="measurement.withdraw",
        entity="measurement",
        entity_id=m.id,
        experiment_id=trial.experiment_id,
        trial_id=trial.id,
        before=None if before is None else repr(before),
        after=None if objective is None else repr(objective),
        detail={"value": m.value, "unit": m.unit, "source": m.source, "reason": reason},
        now=now,
    )
    touch_id(session, trial.experiment_id)
    receipt = MeasurementReceipt.build(trial, [MeasurementRead.model_validate(m)])
    session.flush()
    return receipt


def supersede_measurement(
    session: Session, measurement_id: int, body: SupersedeIn, *, actor: Actor
) -> MeasurementReceipt:
    """Replace a repeat by a corrected value: the old one is kept, withdrawn with the reason;
    the new one (same source) points to it; the objective is recomputed (flushed)."""
    m, trial = _correctable(session, measurement_id)
    exp = trial.experiment
    check_value(body.value, body.unit, exp.objective_unit, what="the corrected value")
    now = utcnow()
    before = trial.objective
    _withdraw(m, body.reason, actor, now)
    session.flush()
    stored = store_measurement(
        session,
        trial,
        [(body.value, body.unit, body.note or f"corrects {m.value:g} {m.unit}")],
        actor=actor,
        source=m.source,
        objective_sources=objective_sources_of(exp),
        supersedes_id=m.id,
    )
    record(
        session,
        actor=actor.username,
        action="measurement.supersede",
        entity="measurement",
        entity_id=m.id,
        experiment_id=trial.experiment_id,
        trial_id=trial.id,
        before=repr(m.value),
        after=repr(body.value),
        detail={
            "reason": body.reason,
            "objective_before": before,
            "objective_after": trial.objective,
            "new_measurement_id": stored[0].id,
        },
        now=now,
    )
    touch_id(session, trial.experiment_id)
    receipt = MeasurementReceipt.build(trial, stored)
    session.flush()
    return receipt


def _request_sha256(trial_id: int, body: MeasurementsIn) -> str:
    blob = json.dumps({"trial_id": trial_id, **body.model_dump()}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _check_key_unused(db: Connection, key: str, digest: str) -> None:
    """DuplicateRequest (with the first post's receipt) if ``key`` was applied to this very
    request; Conflict if it was used for another."""
    seen = db.execute(_KEY_SEEN, {"scope": "measurements", "key": key}).first()
    if seen is None:
        return
    if seen.request_sha256 == digest:
        raise DuplicateRequest(
            f"duplicate post: Idempotency-Key {key!r} was already applied ({seen.summary}); "
            "nothing stored again",
            receipt=seen.receipt,
        )
    raise Conflict(
        f"Idempotency-Key {key!r} was already used for a different request ({seen.summary}); "
        "use a new key"
    )


def add_measurements(
    session: Session,
    trial_id: int,
    body: MeasurementsIn,
    *,
    idempotency_key: str | None,
    actor: Actor,
) -> MeasurementReceipt:
    """Record an operator's repeats for a trial, once per Idempotency-Key.

    A queued or running trial without a worker's lease becomes completed; a completed one
    gets its objective recomputed; a needs_review one keeps its status (a person decides).
    """
    if not idempotency_key or not (1 <= len(idempotency_key) <= 200):
        raise InvalidInput("the Idempotency-Key header is required (1-200 characters)")
    if not idempotency_key.isprintable():
        raise InvalidInput("the Idempotency-Key header must be printable text")
    digest = _request_sha256(trial_id, body)
    db = session.connection()
    found = db.execute(
        _TRIAL_TO_MEASURE, {"trial_id": trial_id, "scope": "measurements", "key": idempotency_key}
    ).fetchone()
    if found is None:
        raise NotFound(f"trial {trial_id} not found")
    row = _TrialToMeasure._make(found)
    if row.key_seen:
        _check_key_unused(db, idempotency_key, digest)
    if row.status not in MEASURABLE:
        raise IllegalTransition(
            f"cannot add measurements: trial #{row.index} is {row.status}"
            + (" (confirm and run it first)" if row.status in lc.PENDING else ""),
            current=row.status,
        )
    for i, rep in enumerate(body.repeats):
        check_value(rep.value, rep.unit, row.objective_unit, what=f"repeat {i + 1}")
    sources = sources_list(row.objective_sources, row.task, row.target)
    typed = sources[0] if sources[0] in ("tape", "tracker") else "tape"
    values = [(r.value, r.unit, r.note, r.source or typed) for r in body.repeats]
    # The first measurement of an unleased trial completes it: a status change, made by the
    # lifecycle on the ORM object. Later ones only touch the row (and the ORM object, when
    # the session holds one, so that it is not left stale).
    completes = row.status in (lc.QUEUED, lc.RUNNING) and not row.leased
    trial: Any = session.identity_map.get(_TRIAL_KEY((trial_id,)))
    if trial is None:
        trial = session.get(Trial, trial_id) if completes else SimpleNamespace(**row._asdict())
    stored = store_measurement(
        session, trial, values, actor=actor, source="tape", objective_sources=sources
    )
    if completes:
        lc.transition(
            session, trial, lc.COMPLETED, actor=actor.username, reason="measured by the operator"
        )
    receipt = MeasurementReceipt.build(trial, stored)
    try:
        db.execute(
            _INSERT_KEY,
            {
                "scope": "measurements",
                "key": idempotency_key,
                "request_sha256": digest,
                "summary": f"trial {trial_id}, {len(stored)} repeat(s)",
                "receipt": receipt.model_dump(mode="json"),
                "created_by": actor.username,
                "created_at": utcnow(),
            },
        )
    except IntegrityError:  # the same key, committed by a concurrent post since our check
        session.rollback()
        _check_key_unused(session.connection(), idempotency_key, digest)
        raise
    touch_id(session, trial.experiment_id, connection=db)
    return receipt
