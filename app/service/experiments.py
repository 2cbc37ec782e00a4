"""Experiments: create, read, change; and the policy (θ ↔ schedule, limits) each one implies."""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import bindparam, func, select, update
from sqlalchemy import inspect as sa_inspect
from sqlalchemy.engine import Connection
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import AuditLog, Experiment, Trial
from app.optim.methods import METHODS, OptimizerSpec
from app.policy import RELEASE_TASKS, HardwareCeilings, Policy, PolicyError, PressureLimits
from app.service.audit import record
from app.service.auth import Actor
from app.service.drift import (
    REFERENCE,
    apply_reference,
    check_age_halflife,
    check_no_age_in_settings,
    optimizer_settings_with_age,
)
from app.service.errors import InvalidInput, NotFound
from app.service.lifecycle import COMPLETED
from app.service.schemas import (
    REFERENCE_COUNT,
    AuditRead,
    ExperimentCreate,
    ExperimentPatch,
    ExperimentRead,
)

DEFAULT_UNIT = {"tip_speed": "m/s", "throw": "score", "hammer": "score"}


def policy_of(exp: Experiment) -> Policy:
    """The Policy that decodes this experiment's θ (with its limits, if any)."""
    return Policy(
        levels=exp.levels,
        horizon=exp.horizon,
        with_release=exp.with_release,
        limits=exp.limits,
    )


def executed_theta(
    exp: Experiment, planned_theta: Any, executed_schedule_pa: Any, executed_release_step: Any
) -> list[float]:
    """The θ the optimiser observes for a trial of ``exp`` that ran ``executed_schedule_pa``:
    ``Policy.executed_theta``, the one rule (the planned θ when the trial ran its plan)."""
    theta = policy_of(exp).executed_theta(
        np.asarray(planned_theta, dtype=np.float64), executed_schedule_pa, executed_release_step
    )
    return [float(v) for v in theta]


def touch(exp: Experiment) -> None:
    """Mark the experiment changed (its version is the live pages' change signal)."""
    exp.version = (exp.version or 0) + 1
    exp.updated_at = utcnow()


_TOUCH = (
    update(Experiment.__table__)
    .where(Experiment.__table__.c.id == bindparam("experiment_id"))
    .values(version=Experiment.__table__.c.version + 1, updated_at=bindparam("now"))
)


def touch_id(session: Session, experiment_id: int, *, connection: Connection | None = None) -> None:
    """``touch`` by id: in SQL when the experiment is not loaded (no need to load it), on the
    loaded object otherwise (an UPDATE behind its back would leave its version stale).
    ``connection``: the session's, when the caller holds it already."""
    key = sa_inspect(Experiment).identity_key_from_primary_key((experiment_id,))
    if key in session.identity_map:
        touch(session.identity_map[key])
        return
    conn = connection or session.connection()
    conn.execute(_TOUCH, {"experiment_id": experiment_id, "now": utcnow()})


def optimizer_spec(exp: Experiment) -> OptimizerSpec:
    """What ``app.optim.build_optimizer`` builds this experiment's optimiser from."""
    return OptimizerSpec(
        exp.method,
        levels=exp.levels,
        horizon=exp.horizon,
        with_release=exp.with_release,
        seed=exp.seed,
        settings=optimizer_settings_with_age(exp),
        n_initial=exp.n_initial,
        acquisition=exp.acquisition,
        kappa=exp.kappa,
    )


def create_experiment(
    session: Session,
    spec: ExperimentCreate,
    *,
    actor: Actor,
    ceilings: HardwareCeilings | None = None,
) -> Experiment:
    """Validate and store a new experiment (flushed; the caller's ``Database.write`` commits).

    A hardware experiment's limits must lie within ``ceilings`` (the server's settings; the
    paper robot's when None): they can only narrow them."""
    from app.optim import OptimError, build_optimizer

    with_release = (
        spec.with_release if spec.with_release is not None else spec.task in RELEASE_TASKS
    )
    if spec.target == "hardware" and spec.limits is None:
        raise InvalidInput(
            "a hardware experiment needs limits (nominal_pa, max_step_pa, source_pa)"
        )
    limits = None
    if spec.limits is not None:
        nominal = spec.limits.nominal_pa
        if isinstance(nominal, list) and len(nominal) not in (1, 12):
            raise InvalidInput(f"limits.nominal_pa needs 1 or 12 values, got {len(nominal)}")
        try:
            limits = PressureLimits(
                nominal_pa=tuple(nominal) if isinstance(nominal, list) else (nominal,),
                max_step_pa=spec.limits.max_step_pa,
                source_pa=spec.limits.source_pa,
            )
        except (PolicyError, ValueError) as exc:
            raise InvalidInput(f"limits: {_in_kpa(str(exc))}") from None
        if spec.target == "hardware":
            try:
                (ceilings or HardwareCeilings()).check_limits(limits)
            except PolicyError as exc:
                raise InvalidInput(f"limits: {exc}") from None
    try:
        policy = Policy(
            levels=spec.levels, horizon=spec.horizon, with_release=with_release, limits=limits
        )
    except PolicyError as exc:
        raise InvalidInput(str(exc)) from None
    if spec.method not in METHODS:
        raise InvalidInput(f"method {spec.method!r} is not one of {', '.join(METHODS)}")
    check_no_age_in_settings(spec.optimizer_settings)
    check_age_halflife(spec.method, spec.age_halflife_trials)
    n_initial = spec.n_initial if spec.n_initial is not None else policy.dim + 1
    if spec.budget is not None and n_initial > spec.budget and spec.method in _bo_methods():
        raise InvalidInput(
            f"n_initial: {n_initial} random initial trials do not fit in a budget of "
            f"{spec.budget} trials; lower n_initial or raise the budget"
        )
    exp = Experiment(
        name=spec.name,
        task=spec.task,
        target=spec.target,
        sim_preset=spec.sim_preset,
        command_hold=spec.command_hold,
        objective_unit=spec.objective_unit or DEFAULT_UNIT[spec.task],
        levels=spec.levels,
        horizon=spec.horizon,
        with_release=with_release,
        limits_nominal_pa=list(limits.nominal_pa) if limits else None,
        limits_max_step_pa=limits.max_step_pa if limits else None,
        limits_source_pa=limits.source_pa if limits else None,
        method=spec.method,
        acquisition=spec.acquisition,
        kappa=spec.kappa,
        n_initial=n_initial,
        seed=spec.seed,
        optimizer_settings=dict(spec.optimizer_settings),
        objective_sources=",".join(dict.fromkeys(spec.objective_sources))
        if spec.objective_sources
        else None,
        budget=spec.budget,
        status="active",
        notes=spec.notes,
        version=1,
        created_by=actor.username,
        age_halflife_trials=spec.age_halflife_trials,
        drift_baseline_n=3,
    )
    if spec.reference is not None:
        if spec.reference.theta_from == "trial":
            raise InvalidInput(
                "reference.theta_from: a new experiment has no trials to choose from; start "
                "with the incumbent, or choose a trial later (PUT /api/experiments/{id}/reference)"
            )
        apply_reference(session, exp, spec.reference, actor=actor)
    try:  # refuse settings the optimiser would refuse later, now, with its message
        build_optimizer(optimizer_spec(exp))
    except (OptimError, ValueError, TypeError) as exc:
        raise InvalidInput(f"optimizer settings: {exc}") from None
    _check_preset(spec.sim_preset)
    session.add(exp)
    session.flush()
    record(
        session,
        actor=actor.username,
        action="experiment.create",
        entity="experiment",
        entity_id=exp.id,
        experiment_id=exp.id,
        after="active",
        detail={
            "name": exp.name,
            "task": exp.task,
            "target": exp.target,
            **({"reference_every": exp.reference_every} if exp.reference_every else {}),
        },
    )
    if spec.sim_prior_experiment_id is not None:  # checked like a later link (422: what differs)
        from app.service.sim_prior import link

        link(session, exp.id, spec.sim_prior_experiment_id, actor=actor)
    session.flush()
    return exp


def _bo_methods() -> frozenset[str]:
    from app.optim import BO_METHODS

    return frozenset(BO_METHODS)


def _in_kpa(message: str) -> str:
    """A limits message of ``PressureLimits`` with its Pa numbers also in kPa."""
    import re

    def kpa(m: re.Match[str]) -> str:
        return f"{float(m.group(1)) / 1000.0:g} kPa"

    num = r"(-?[0-9.]+(?:e[+-]?[0-9]+)?)"

    def span(m: re.Match[str]) -> str:
        lo, hi = (float(m.group(i)) / 1000.0 for i in (1, 2))
        return f"[{lo:g}, {hi:g}] kPa"

    message = re.sub(rf"\[{num}, {num}\] Pa\b", span, message)
    return re.sub(rf"{num} Pa\b", kpa, message)


def _check_preset(preset: str) -> None:
    try:
        from app.sim import PRESETS
    except ImportError:  # the simulator package is optional for a pure-hardware server
        return
    if preset not in PRESETS:
        raise InvalidInput(f"sim_preset {preset!r} is not one of {', '.join(PRESETS)}")


def get_experiment(session: Session, experiment_id: int, *, for_update: bool = False) -> Experiment:
    """The experiment or NotFound; ``for_update`` locks its row (PostgreSQL)."""
    exp = session.get(Experiment, experiment_id, with_for_update=for_update or None)
    if exp is None:
        raise NotFound(f"experiment {experiment_id} not found")
    return exp


def _stats(session: Session, ids: list[int]) -> tuple[dict[int, dict[str, int]], dict[int, Any]]:
    counts: dict[int, dict[str, int]] = {i: {} for i in ids}
    if not ids:
        return counts, {}
    rows = session.execute(
        select(Trial.experiment_id, Trial.status, func.count())
        .where(Trial.experiment_id.in_(ids))
        .group_by(Trial.experiment_id, Trial.status)
    ).all()
    for eid, status, n in rows:
        counts[eid][status] = n
    # ran, but no measurement from the objective's sources yet: what an operator must measure
    awaiting = session.execute(
        select(Trial.experiment_id, func.count())
        .where(
            Trial.experiment_id.in_(ids),
            Trial.status == COMPLETED,
            Trial.objective.is_(None),
        )
        .group_by(Trial.experiment_id)
    ).all()
    for eid, n in awaiting:
        counts[eid]["awaiting_measurement"] = n
    # reference trials (drift checks) that are not abandoned: outside the budget
    references = session.execute(
        select(Trial.experiment_id, func.count())
        .where(
            Trial.experiment_id.in_(ids),
            Trial.source == REFERENCE,
            Trial.status != "abandoned",
        )
        .group_by(Trial.experiment_id)
    ).all()
    for eid, n in references:
        counts[eid][REFERENCE_COUNT] = n
    best: dict[int, tuple[int, float, int]] = {}
    rows2 = session.execute(
        select(Trial.experiment_id, Trial.id, Trial.objective, Trial.index)
        .where(
            Trial.experiment_id.in_(ids),
            Trial.status == COMPLETED,
            Trial.objective.is_not(None),
        )
        .order_by(Trial.experiment_id, Trial.objective.desc(), Trial.index)
    ).all()
    for eid, tid, obj, index in rows2:
        if eid not in best and obj is not None:  # the query keeps only objectives
            best[eid] = (tid, obj, index)
    return counts, best


def read_experiment(session: Session, experiment_id: int) -> ExperimentRead:
    """One experiment with counts and best objective."""
    exp = get_experiment(session, experiment_id)
    counts, best = _stats(session, [exp.id])
    return ExperimentRead.build(exp, status_counts=counts[exp.id], best=best.get(exp.id))


def list_experiments(session: Session) -> list[ExperimentRead]:
    """All experiments, newest first."""
    exps = list(session.scalars(select(Experiment).order_by(Experiment.id.desc())))
    counts, best = _stats(session, [e.id for e in exps])
    return [ExperimentRead.build(e, status_counts=counts[e.id], best=best.get(e.id)) for e in exps]


def patch_experiment(
    session: Session, experiment_id: int, patch: ExperimentPatch, *, actor: Actor
) -> ExperimentRead:
    """Change status / notes / budget (audited; ``Database.write`` commits)."""
    exp = get_experiment(session, experiment_id)
    changes = patch.model_dump(exclude_unset=True)
    if "age_halflife_trials" in changes:
        check_age_halflife(exp.method, changes["age_halflife_trials"])
    if changes.get("budget") is not None:
        used = session.scalar(
            select(func.count())
            .select_from(Trial)
            .where(
                Trial.experiment_id == exp.id,
                Trial.status != "abandoned",
                Trial.source != REFERENCE,
            )
        )
        if changes["budget"] < (used or 0):
            raise InvalidInput(
                f"budget: {changes['budget']} trials is below the {used} trials this experiment "
                "already has (abandoned and reference trials not counted)"
            )
    for field, value in changes.items():
        if field in ("status", "notes") and value is None:
            raise InvalidInput(f"{field} cannot be null")
        before = getattr(exp, field)
        if before == value:
            continue
        setattr(exp, field, value)
        record(
            session,
            actor=actor.username,
            action=f"experiment.{field}",
            entity="experiment",
            entity_id=exp.id,
            experiment_id=exp.id,
            before=None if before is None else str(before)[:2000],
            after=None if value is None else str(value)[:2000],
        )
    touch(exp)
    session.flush()
    return read_experiment(session, exp.id)


def experiment_version(session: Session, experiment_id: int) -> int:
    """The experiment's change counter."""
    v = session.scalar(select(Experiment.version).where(Experiment.id == experiment_id))
    if v is None:
        raise NotFound(f"experiment {experiment_id} not found")
    return int(v)


def audit_log(session: Session, experiment_id: int, *, limit: int = 500) -> list[AuditRead]:
    """The experiment's audit rows, newest first."""
    get_experiment(session, experiment_id)
    rows = session.scalars(
        select(AuditLog)
        .where(AuditLog.experiment_id == experiment_id)
        .order_by(AuditLog.id.desc())
        .limit(limit)
    )
    return [AuditRead.model_validate(r) for r in rows]
