"""Measurements: every raw repeat kept; a trial's objective is their mean, with its SEM."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence

import numpy as np
from sqlalchemy import bindparam, insert, select
from sqlalchemy import inspect as sa_inspect
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import Experiment, IdempotencyKey, Measurement, Trial
from app.service import lifecycle as lc
from app.service.artifacts import has_trajectory
from app.service.audit import record
from app.service.auth import Actor
from app.service.errors import Conflict, DuplicateRequest, IllegalTransition, InvalidInput
from app.service.experiments import touch_id
from app.service.schemas import MeasuredTrial, MeasurementRead, MeasurementsIn

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
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        raise ValueError("no repeats")
    mean = float(v.mean())
    if v.size < 2:
        return mean, None
    return mean, float(v.std(ddof=1) / math.sqrt(v.size))


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


# Built once: constructing a statement costs more than running it on SQLite, and a
# measurement post is the service's most frequent write.
_MEASUREMENTS = Measurement.__table__
_REPEATS_OF = (
    select(_MEASUREMENTS)
    .where(_MEASUREMENTS.c.trial_id == bindparam("trial_id"))
    .order_by(_MEASUREMENTS.c.id)
)
_INSERT_REPEAT = insert(_MEASUREMENTS).returning(_MEASUREMENTS.c.id)
_KEYS = IdempotencyKey.__table__
_KEY_SEEN = select(_KEYS.c.request_sha256, _KEYS.c.summary).where(
    _KEYS.c.scope == bindparam("scope"), _KEYS.c.key == bindparam("key")
)
_INSERT_KEY = insert(_KEYS)
_UNIT_OF = select(Experiment.__table__.c.objective_unit).where(
    Experiment.__table__.c.id == bindparam("experiment_id")
)


def store_measurement(
    session: Session,
    trial: Trial,
    values: Sequence[tuple[float, str, str]],
    *,
    actor: Actor,
    source: str,
) -> list[MeasurementRead]:
    """Append raw repeats (value, unit, note) to ``trial`` (already flushed, so it has an id)
    and refresh its objective, SEM and count from all its repeats.

    Returns every repeat of the trial, oldest first, the new ones last.
    """
    now = utcnow()
    db = session.connection()
    repeats = [
        MeasurementRead.model_validate(r, from_attributes=True)
        for r in db.execute(_REPEATS_OF, {"trial_id": trial.id})
    ]
    for v, u, note in values:
        row = {
            "trial_id": trial.id,
            "value": float(v),
            "unit": u,
            "note": note,
            "source": source,
            "created_by": actor.username,
            "created_at": now,
        }
        repeats.append(MeasurementRead(id=db.execute(_INSERT_REPEAT, row).scalar_one(), **row))
    if "measurements" in sa_inspect(trial).dict:  # a collection loaded earlier is now stale
        session.expire(trial, ["measurements"])
    before = trial.objective
    trial.objective, trial.objective_sem = objective_from_repeats([m.value for m in repeats])
    trial.n_measurements = len(repeats)
    trial.updated_at = now
    record(
        session,
        actor=actor.username,
        action="trial.measure",
        entity="trial",
        entity_id=trial.id,
        experiment_id=trial.experiment_id,
        trial_id=trial.id,
        before=None if before is None else repr(before),
        after=repr(trial.objective),
        detail={
            "source": source,
            "values": [float(v) for v, _, _ in values],
        },
        now=now,
    )
    return repeats


def _request_sha256(trial_id: int, body: MeasurementsIn) -> str:
    blob = json.dumps({"trial_id": trial_id, **body.model_dump()}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def add_measurements(
    session: Session,
    trial_id: int,
    body: MeasurementsIn,
    *,
    idempotency_key: str | None,
    actor: Actor,
) -> MeasuredTrial:
    """Record an operator's repeats for a trial, once per Idempotency-Key (committed).

    A queued or running trial without a worker's lease becomes completed; a completed one
    gets its objective recomputed; a needs_review one keeps its status (a person decides).
    """
    from app.service.trials import active_lease, get_trial

    if not idempotency_key or not (1 <= len(idempotency_key) <= 200):
        raise InvalidInput("the Idempotency-Key header is required (1-200 characters)")
    if not idempotency_key.isprintable():
        raise InvalidInput("the Idempotency-Key header must be printable text")
    digest = _request_sha256(trial_id, body)
    db = session.connection()
    seen = db.execute(_KEY_SEEN, {"scope": "measurements", "key": idempotency_key}).first()
    if seen is not None:
        if seen.request_sha256 == digest:
            raise DuplicateRequest(
                f"duplicate post: Idempotency-Key {idempotency_key!r} was already applied "
                f"({seen.summary}); nothing stored again"
            )
        raise Conflict(
            f"Idempotency-Key {idempotency_key!r} was already used for a different request "
            f"({seen.summary}); use a new key"
        )
    trial = get_trial(session, trial_id, for_update=True)
    if trial.status not in MEASURABLE:
        raise IllegalTransition(
            f"cannot add measurements: trial {trial.id} is {trial.status}"
            + (" (confirm and run it first)" if trial.status in lc.PENDING else ""),
            current=trial.status,
        )
    unit = db.execute(_UNIT_OF, {"experiment_id": trial.experiment_id}).scalar_one()
    for i, rep in enumerate(body.repeats):
        check_value(rep.value, rep.unit, unit, what=f"repeats[{i}].value")
    repeats = store_measurement(
        session,
        trial,
        [(r.value, r.unit, r.note) for r in body.repeats],
        actor=actor,
        source="operator",
    )
    if trial.status in (lc.QUEUED, lc.RUNNING) and active_lease(session, trial.id) is None:
        lc.transition(
            session, trial, lc.COMPLETED, actor=actor.username, reason="measured by the operator"
        )
    db.execute(
        _INSERT_KEY,
        {
            "scope": "measurements",
            "key": idempotency_key,
            "request_sha256": digest,
            "summary": f"trial {trial.id}, {len(body.repeats)} repeat(s)",
            "created_by": actor.username,
            "created_at": utcnow(),
        },
    )
    touch_id(session, trial.experiment_id)
    reply = MeasuredTrial.build_measured(
        trial, repeats, has_trajectory=has_trajectory(session, trial.id)
    )
    session.commit()  # one flush (the trial's new objective) and one commit in all
    return reply
