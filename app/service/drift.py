"""Drift checks: a reference θ run again every k hardware trials, its scores against a band,
and a warning (on the page, in the audit log) when the latest one falls outside it; and the
BO's weighing of data by age (``age_halflife_trials``).

The rules (docs/ARCHITECTURE.md, "Drift checks"):

* **Schedule.** Every k-th hardware trial is a reference (k ≥ 2): after k − 1 ordinary
  trials (suggested or attached; abandoned and imported ones not counted) since the last
  reference, or since the start, ``POST /suggest`` puts a reference trial in the queue before
  the next suggestion. A reference is a normal trial with ``source = "reference"``: previewed
  and confirmed like any other (the safety gate is the same), never an optimiser suggestion.
* **The θ.** A chosen trial's planned θ, or "the incumbent": the best scored trial (highest
  objective, completed, lowest number on ties) at the moment the first reference is made;
  that θ is then frozen (``reference_theta``) so that every reference repeats one schedule.
  No reference is made while there is no incumbent yet, nor while the reference's schedule is
  one an operator abandoned (choose another reference).
* **Budget.** References do not count against the budget: it caps the trials the optimiser
  learns from, so a drift-checked experiment gets as many suggestions as one without.
* **Observed.** Each scored reference is one observation at its executed θ, like any trial
  (the GP sees the repeats at that θ, so it learns the noise and, with
  ``age_halflife_trials``, the current level); its θ counts as pending while it waits. It is
  never suggested: the optimiser is asked for the ordinary trials only.
* **Band.** From the first m scored references (``baseline_n``, default 3): centre = their
  mean; half-width = ``tolerance`` if set, else 2 × the larger of their standard deviation
  and the RMS of their own SEMs (the measurement noise). A later reference beyond it has
  shifted; when the latest one has, the page warns, and every change of a reference's
  verdict (a new score, a correction, new band settings) is written to the audit log
  (``drift.shift`` / ``drift.back_in_band``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import AuditLog, Experiment, Trial
from app.policy import schedule_hash
from app.service import lifecycle as lc
from app.service.audit import record
from app.service.auth import Actor
from app.service.errors import InvalidInput
from app.service.schemas import (
    DriftBandRead,
    DriftPointRead,
    DriftRead,
    ExperimentRead,
    ReferenceIn,
)

REFERENCE = "reference"  # Trial.source of a reference trial
#: trials that do not count as the robot's hardware trials for the schedule
_NOT_RUN = frozenset({lc.ABANDONED})
_NOT_HARDWARE_SOURCES = frozenset({"import"})
#: a reference's score is not judged once the trial failed, was abandoned or awaits review
_UNJUDGED = frozenset({lc.FAILED, lc.ABANDONED, lc.NEEDS_REVIEW})
SHIFT, BACK = "drift.shift", "drift.back_in_band"
MAX_EVERY = 10_000


# --- settings --------------------------------------------------------------------------------
def check_age_halflife(method: str, value: float | None) -> None:
    """InvalidInput unless ``value`` is None or a positive half-life for a BO method."""
    from app.optim.methods import BO_METHODS

    if value is None:
        return
    if not (math.isfinite(value) and value > 0):
        raise InvalidInput(
            f"age_halflife_trials: {value!r} is not a positive number of trials (or null: "
            "every observation weighs the same)"
        )
    if method not in BO_METHODS:
        raise InvalidInput(
            f"age_halflife_trials: {method} has no GP to weigh data by age; use a BO method "
            f"({', '.join(BO_METHODS)}) or leave it out"
        )


def check_no_age_in_settings(settings: dict[str, Any]) -> None:
    """One way to set it: the experiment's own field, not a key of optimizer_settings."""
    if "age_halflife_trials" in settings:
        raise InvalidInput(
            "optimizer_settings: set age_halflife_trials as the experiment's own field "
            "(age_halflife_trials), not inside optimizer_settings"
        )


def optimizer_settings_with_age(exp: Experiment) -> dict[str, Any]:
    """The experiment's optimiser settings with its ``age_halflife_trials`` (if set)."""
    settings = dict(exp.optimizer_settings or {})
    if exp.age_halflife_trials is not None:
        settings["age_halflife_trials"] = float(exp.age_halflife_trials)
    return settings


def _check_every(every: int) -> None:
    if every < 2:
        raise InvalidInput(
            f"reference.every: k = {every} is too small; every k-th hardware trial is a "
            "reference, so k must be at least 2 (1 would make every trial a reference)"
        )
    if every > MAX_EVERY:
        raise InvalidInput(f"reference.every: k = {every} is above {MAX_EVERY} trials")


def apply_reference(
    session: Session, exp: Experiment, body: ReferenceIn | None, *, actor: Actor
) -> None:
    """Set (or with None, stop) the experiment's drift check, validated and audited (flushed;
    the caller's ``Database.write`` commits)."""
    before = _describe(exp)
    if body is None:
        exp.reference_every = None
        exp.reference_theta_from = None
        exp.reference_trial_id = None
        exp.reference_theta = None
    else:
        if exp.target != "hardware":
            raise InvalidInput(
                "reference: drift checks are for hardware experiments (the simulator gives a "
                "θ the same score every time)"
            )
        _check_every(body.every)
        trial_id: int | None = None
        theta: list[float] | None = None
        if body.theta_from == "trial":
            if body.trial_index is None:
                raise InvalidInput(
                    "reference.trial_index: give the number of the trial whose θ to repeat "
                    "(or theta_from = incumbent)"
                )
            chosen = (
                session.scalars(
                    select(Trial).where(
                        Trial.experiment_id == exp.id, Trial.index == body.trial_index
                    )
                ).first()
                if exp.id is not None
                else None
            )
            if chosen is None:
                raise InvalidInput(
                    f"reference.trial_index: this experiment has no trial {body.trial_index}"
                )
            if chosen.status == lc.ABANDONED:
                raise InvalidInput(
                    f"reference.trial_index: trial {chosen.index} was abandoned (its schedule "
                    "is never run again); choose another"
                )
            trial_id, theta = chosen.id, [float(v) for v in chosen.theta]
        elif body.trial_index is not None:
            raise InvalidInput(
                "reference.trial_index: only with theta_from = trial (the incumbent is found "
                "by the service)"
            )
        keep = (
            body.theta_from == "incumbent"
            and exp.reference_theta_from == "incumbent"
            and exp.reference_every is not None
        )
        exp.reference_every = body.every
        exp.reference_theta_from = body.theta_from
        if not keep:  # a new reference θ (an incumbent already frozen stays frozen)
            exp.reference_trial_id = trial_id
            exp.reference_theta = theta
        exp.drift_baseline_n = body.baseline_n
        exp.drift_tolerance = body.tolerance
    after = _describe(exp)
    if exp.id is not None and after != before:
        record(
            session,
            actor=actor.username,
            action="experiment.reference",
            entity="experiment",
            entity_id=exp.id,
            experiment_id=exp.id,
            before=before,
            after=after,
        )


def _describe(exp: Experiment) -> str | None:
    if exp.reference_every is None:
        return None
    what = exp.reference_theta_from or "incumbent"
    if exp.reference_trial_id is not None:
        what += f" (trial id {exp.reference_trial_id})"
    band = f"± {exp.drift_tolerance:g}" if exp.drift_tolerance is not None else "± 2 × spread"
    return f"every {exp.reference_every}: {what}; band of the first {exp.drift_baseline_n} {band}"


# --- the schedule ----------------------------------------------------------------------------
@dataclass(frozen=True)
class ReferencePlan:
    """Where references go among the next ordinary trials: ``before[i]`` is True when a
    reference trial comes just before ordinary slot i; ``theta`` is the reference θ."""

    before: tuple[bool, ...]
    theta: list[float] | None
    note: str = ""


def _ordinary_since_last_reference(rows: list[Any]) -> int:
    """Ordinary hardware trials after the last reference (all of them before the first)."""
    n = 0
    for source, status in reversed(rows):
        if status in _NOT_RUN or source in _NOT_HARDWARE_SOURCES:
            continue
        if source == REFERENCE:
            return n
        n += 1
    return n


def _trial_rows(session: Session, exp: Experiment) -> list[Any]:
    return list(
        session.execute(
            select(Trial.source, Trial.status)
            .where(Trial.experiment_id == exp.id)
            .order_by(Trial.index)
        ).all()
    )


def incumbent(session: Session, exp: Experiment) -> Trial | None:
    """The experiment's best completed, scored trial (the lowest index on ties), or None."""
    return session.scalars(
        select(Trial)
        .where(
            Trial.experiment_id == exp.id,
            Trial.status == lc.COMPLETED,
            Trial.objective.is_not(None),
        )
        .order_by(Trial.objective.desc(), Trial.index)
    ).first()


def _abandoned_hashes(session: Session, exp: Experiment) -> set[str]:
    rows = session.execute(
        select(Trial.pressure_schedule_pa, Trial.release_step).where(
            Trial.experiment_id == exp.id, Trial.status == lc.ABANDONED
        )
    ).all()
    return {schedule_hash(s, r) for s, r in rows}


def _theta_hash(exp: Experiment, theta: list[float]) -> str:
    from app.service.experiments import policy_of

    d = policy_of(exp).decode(np.asarray(theta, dtype=np.float64))
    return schedule_hash(d.pressure_schedule_pa, d.release_step)


def _paused_reason(session: Session, exp: Experiment) -> str:
    """Why no reference can be made now ("" when one can)."""
    if exp.reference_theta is None:
        if exp.reference_theta_from == "incumbent" and incumbent(session, exp) is None:
            return "the first reference waits for a scored trial (the incumbent)"
        return ""
    if _theta_hash(exp, exp.reference_theta) in _abandoned_hashes(session, exp):
        return (
            "the reference's schedule was abandoned by an operator; no more references are "
            "made until another reference θ is chosen"
        )
    return ""


def plan_references(session: Session, exp: Experiment, n: int, *, actor: Actor) -> ReferencePlan:
    """Where the due references go among the next ``n`` ordinary trials (in the caller's
    write transaction). The first reference of an incumbent schedule freezes the incumbent's
    θ (audited ``experiment.reference_frozen``)."""
    if exp.reference_every is None or exp.target != "hardware" or n < 1:
        return ReferencePlan((False,) * max(n, 0), None)
    if _paused_reason(session, exp):
        return ReferencePlan((False,) * n, None)
    k = exp.reference_every
    count = _ordinary_since_last_reference(_trial_rows(session, exp))
    before = []
    for _ in range(n):
        due = count >= k - 1
        before.append(due)
        count = 1 if due else count + 1
    if not any(before):
        return ReferencePlan(tuple(before), None)
    if exp.reference_theta is None:  # incumbent: freeze it now
        best = incumbent(session, exp)
        assert best is not None  # _paused_reason said one exists
        exp.reference_trial_id = best.id
        exp.reference_theta = [float(v) for v in best.theta]
        record(
            session,
            actor=actor.username,
            action="experiment.reference_frozen",
            entity="experiment",
            entity_id=exp.id,
            experiment_id=exp.id,
            trial_id=best.id,
            after=f"the incumbent, trial {best.index} ({best.objective!r})",
            detail={"theta": exp.reference_theta, "objective": best.objective},
        )
    index = session.scalar(select(Trial.index).where(Trial.id == exp.reference_trial_id))
    note = f"drift check: the reference θ (trial {index}) every {k} hardware trials"
    return ReferencePlan(tuple(before), list(exp.reference_theta), note)


# --- the chart, the band, the warning --------------------------------------------------------
def _points(session: Session, exp: Experiment) -> tuple[list[Any], list[Any]]:
    """Scored references of the current reference θ, and of earlier ones (index order)."""
    rows = session.execute(
        select(
            Trial.id,
            Trial.index,
            Trial.objective,
            Trial.objective_sem,
            Trial.finished_at,
            Trial.status,
            Trial.pressure_schedule_pa,
            Trial.release_step,
        )
        .where(
            Trial.experiment_id == exp.id,
            Trial.source == REFERENCE,
            Trial.objective.is_not(None),
        )
        .order_by(Trial.index)
    ).all()
    current = _theta_hash(exp, exp.reference_theta) if exp.reference_theta is not None else None
    now, earlier = [], []
    for r in rows:
        if r.status in _UNJUDGED:
            continue
        if current is not None and schedule_hash(r.pressure_schedule_pa, r.release_step) == current:
            now.append(r)
        else:
            earlier.append(r)
    return now, earlier


def band_of(
    scores: list[float], sems: list[float | None], tolerance: float | None
) -> DriftBandRead:
    """The band from the baseline's scores (and their SEMs): see the module's docstring."""
    center = math.fsum(scores) / len(scores)
    if tolerance is not None:
        half, rule = float(tolerance), f"the experiment's tolerance ± {tolerance:g}"
    else:
        n = len(scores)
        std = math.sqrt(math.fsum((s - center) ** 2 for s in scores) / (n - 1)) if n > 1 else 0.0
        known = [s for s in sems if s is not None]
        noise = math.sqrt(math.fsum(s * s for s in known) / len(known)) if known else 0.0
        spread = max(std, noise)
        half = 2.0 * spread
        rule = (
            f"2 × the first {n} references' "
            + ("std" if std >= noise else "measurement SEM (RMS)")
            + f" ({spread:.4g})"
        )
    return DriftBandRead(
        center=center, half_width=half, low=center - half, high=center + half, rule=rule
    )


def _judge(exp: Experiment, rows: list[Any]) -> tuple[DriftBandRead | None, list[DriftPointRead]]:
    m = exp.drift_baseline_n
    band = None
    if len(rows) >= m:
        base = rows[:m]
        band = band_of(
            [float(r.objective) for r in base],
            [None if r.objective_sem is None else float(r.objective_sem) for r in base],
            exp.drift_tolerance,
        )
    points = []
    for i, r in enumerate(rows):
        baseline = i < m
        outside = (
            band is not None
            and not baseline
            and abs(float(r.objective) - band.center) > band.half_width
        )
        points.append(_point(r, baseline=baseline, outside=outside))
    return band, points


def _point(r: Any, *, baseline: bool = False, outside: bool = False) -> DriftPointRead:
    """A scored reference trial's row as the drift chart plots it."""
    return DriftPointRead(
        trial_id=r.id,
        index=r.index,
        objective=float(r.objective),
        objective_sem=None if r.objective_sem is None else float(r.objective_sem),
        finished_at=r.finished_at,
        baseline=baseline,
        outside=outside,
    )


def _earlier_points(rows: list[Any]) -> list[DriftPointRead]:
    return [_point(r) for r in rows]


def drift_view(session: Session, experiment_id: int) -> DriftRead:
    """The experiment's drift check: scored references, the band, the warning."""
    from app.service.experiments import get_experiment

    exp = get_experiment(session, experiment_id)
    rows, earlier = _points(session, exp)
    band, points = _judge(exp, rows)
    reference = ExperimentRead.build(exp).reference
    ref_index = None
    if exp.reference_trial_id is not None:
        ref_index = session.scalar(select(Trial.index).where(Trial.id == exp.reference_trial_id))
    shifted = bool(points) and points[-1].outside
    unit = exp.objective_unit
    warning = ""
    if shifted and band is not None:
        last = points[-1]
        warning = (
            f"Drift: reference trial {last.index} scored {last.objective:.4g} {unit}, outside "
            f"the band {band.center:.4g} ± {band.half_width:.3g} {unit} of the first "
            f"{exp.drift_baseline_n} references. The robot may have changed since: check it "
            "(pressures, tracker, wear) before trusting new scores."
        )
    message = ""
    next_in: int | None = None
    if exp.reference_every is None:
        message = "No drift check scheduled."
    else:
        message = _paused_reason(session, exp)
        if not message:
            count = _ordinary_since_last_reference(_trial_rows(session, exp))
            next_in = max(exp.reference_every - 1 - count, 0)
            if band is None:
                message = (
                    f"The band forms once {exp.drift_baseline_n} references are scored "
                    f"({len(points)} so far)."
                )
    return DriftRead(
        experiment_id=exp.id,
        objective_unit=unit,
        reference=reference,
        reference_trial_index=ref_index,
        points=points,
        earlier=_earlier_points(earlier),
        band=band,
        shifted=shifted,
        warning=warning,
        message=message,
        next_reference_in=next_in,
    )


def set_reference(
    session: Session, experiment_id: int, body: ReferenceIn | None, *, actor: Actor
) -> DriftRead:
    """Schedule (or with None, stop) the experiment's drift check; the new view."""
    from app.service.experiments import get_experiment, touch

    exp = get_experiment(session, experiment_id, for_update=True)
    apply_reference(session, exp, body, actor=actor)
    touch(exp)
    session.flush()
    check_drift(session, experiment_id)  # a new band may change the verdicts
    return drift_view(session, experiment_id)


def check_drift(session: Session, experiment_id: int, *, now: datetime | None = None) -> None:
    """After a reference trial's objective or the band's settings changed: judge every scored
    reference again and append ``drift.shift`` / ``drift.back_in_band`` to the audit log for
    each whose verdict changed (a correction of a baseline score, or a new tolerance, moves
    the band for all of them)."""
    exp = session.get(Experiment, experiment_id)
    if exp is None or exp.reference_every is None:
        return
    rows, _ = _points(session, exp)
    band, points = _judge(exp, rows)
    if band is None:
        return
    last: dict[int, str] = {}
    for tid, action in session.execute(
        select(AuditLog.trial_id, AuditLog.action)
        .where(AuditLog.experiment_id == experiment_id, AuditLog.action.in_((SHIFT, BACK)))
        .order_by(AuditLog.id)
    ).all():
        if tid is not None:
            last[tid] = action
    unit = exp.objective_unit
    for p in points:
        if p.baseline:
            continue
        was_out = last.get(p.trial_id) == SHIFT
        if p.outside == was_out:
            continue
        record(
            session,
            actor="service",
            action=SHIFT if p.outside else BACK,
            entity="trial",
            entity_id=p.trial_id,
            experiment_id=experiment_id,
            trial_id=p.trial_id,
            before="in band" if p.outside else "outside the band",
            after="outside the band" if p.outside else "in band",
            detail={
                "objective": p.objective,
                "unit": unit,
                "center": band.center,
                "half_width": band.half_width,
                "rule": band.rule,
            },
            now=now or utcnow(),
        )
