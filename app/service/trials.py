"""Trials: suggest (ask the optimiser, rebuilt from the database), attach, read, fail, abandon,
resolve, confirm (hardware gate) and run in the service (sim, the pre-worker path)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import AuditLog, Confirmation, Experiment, Lease, Preview, Trial
from app.db.session import Database
from app.optim import (
    Observation,
    OptimError,
    Optimizer,
    OptimizerSpec,
    Surrogate,
    build_optimizer,
)
from app.policy import (
    HardwareCeilings,
    Policy,
    PolicyError,
    PressureLimitError,
    check_release_step,
    schedule_hash,
)
from app.service import lifecycle as lc
from app.service.audit import record
from app.service.auth import Actor
from app.service.drift import REFERENCE, plan_references
from app.service.errors import (
    ConfirmationMismatch,
    Conflict,
    InvalidInput,
    NotFound,
    NotPreviewed,
    SafetyViolation,
)
from app.service.experiments import (
    get_experiment,
    optimizer_spec,
    policy_of,
    touch,
)
from app.service.schemas import ResolveIn, TrialDetail, TrialRead
from app.service.sim_prior import basis_of_trial, with_prior


# --- reading ---------------------------------------------------------------------------------
def get_trial(session: Session, trial_id: int, *, for_update: bool = False) -> Trial:
    """The trial or NotFound; ``for_update`` locks its row (PostgreSQL; SQLite's write
    sessions already hold the database's write lock)."""
    trial = session.get(Trial, trial_id, with_for_update=for_update or None)
    if trial is None:
        raise NotFound(f"trial {trial_id} not found")
    return trial


def lock_for(
    session: Session,
    trial_id: int,
    *,
    target: str,
    source: str,
    dest: str,
    action: str,
    other_target: str,
) -> Trial:
    """The trial, its row locked, if it is a ``target`` trial that ``action`` may move from
    ``source`` to ``dest``; else NotFound, Conflict (another target: ``other_target`` says
    what to do instead) or IllegalTransition naming its status."""
    trial = get_trial(session, trial_id, for_update=True)
    if trial.experiment.target != target:
        raise Conflict(f"trial #{trial.index} is a {trial.experiment.target} trial; {other_target}")
    lc.check_transition(trial, dest, action=action)
    if trial.status != source:
        raise lc.IllegalTransition(
            f"cannot {action}: trial #{trial.index} is {trial.status}, not {source}",
            current=trial.status,
        )
    return trial


def read_trial(session: Session, trial_id: int) -> TrialDetail:
    """A trial with its measurements and audit trail."""
    trial = get_trial(session, trial_id)
    audit = list(
        session.scalars(select(AuditLog).where(AuditLog.trial_id == trial.id).order_by(AuditLog.id))
    )
    previews = list(
        session.scalars(select(Preview).where(Preview.trial_id == trial.id).order_by(Preview.id))
    )
    out = TrialDetail.build_detail(trial, audit, previews)
    if trial.experiment.target == "hardware":
        from app.service.twins import twins_of

        out.twins = twins_of(session, trial.id)
    return out


def list_trials(
    session: Session, experiment_id: int, *, status: str | None = None
) -> list[TrialRead]:
    """An experiment's trials in index order (optionally one status)."""
    get_experiment(session, experiment_id)
    if status is not None and status not in lc.STATUSES:
        raise InvalidInput(f"status {status!r} is not one of {', '.join(lc.STATUSES)}")
    q = select(Trial).where(Trial.experiment_id == experiment_id).order_by(Trial.index)
    if status is not None:
        q = q.where(Trial.status == status)
    trials = list(session.scalars(q))
    with_traj = _trials_with_trajectory(session, [t.id for t in trials])
    return [TrialRead.build(t, has_trajectory=t.id in with_traj) for t in trials]


def _trials_with_trajectory(session: Session, ids: list[int]) -> set[int]:
    from app.db.models import Artifact

    if not ids:
        return set()
    return set(
        session.scalars(
            select(Artifact.trial_id).where(
                Artifact.trial_id.in_(ids), Artifact.kind == "trajectory"
            )
        )
    )


# --- creating --------------------------------------------------------------------------------
def decode_checked(policy: Policy, theta: Any) -> tuple[np.ndarray, np.ndarray, int | None]:
    """θ → (θ (D,), schedule (H,12) Pa, release_step), checked against the policy's limits."""
    try:
        decoded = policy.decode(np.asarray(theta, dtype=np.float64))
    except PressureLimitError as exc:
        raise SafetyViolation(f"schedule beyond the pressure limits: {exc}") from None
    except (PolicyError, ValueError, TypeError) as exc:
        raise InvalidInput(str(exc)) from None
    return np.asarray(theta, dtype=np.float64), decoded.pressure_schedule_pa, decoded.release_step


DEFAULT_CEILINGS = HardwareCeilings()


def check_ceilings(
    exp: Experiment, schedule: np.ndarray, ceilings: HardwareCeilings | None
) -> None:
    """A hardware experiment's limits and schedule within the robot's absolute ceilings
    (the server's settings; the paper robot's when None), whatever the experiment says."""
    if exp.target != "hardware":
        return
    ceilings = ceilings or DEFAULT_CEILINGS
    limits = exp.limits
    if limits is None:
        raise SafetyViolation("hardware experiment carries no pressure limits")
    try:
        ceilings.check_limits(limits)
        ceilings.check_schedule(schedule, np.asarray(limits.nominal_pa))
    except PolicyError as exc:
        raise SafetyViolation(f"beyond the robot's hardware ceilings: {exc}") from None


def check_schedule_safe(
    exp: Experiment,
    schedule: Any,
    release_step: int | None,
    *,
    ceilings: HardwareCeilings | None = None,
) -> np.ndarray:
    """Re-check a stored/forged schedule against the experiment's limits and the robot's
    ceilings (SafetyViolation)."""
    policy = policy_of(exp)
    try:
        sched = policy.check(np.asarray(schedule, dtype=np.float64))
    except PressureLimitError as exc:
        raise SafetyViolation(f"schedule beyond the pressure limits: {exc}") from None
    except (PolicyError, ValueError, TypeError) as exc:
        raise SafetyViolation(f"schedule refused: {exc}") from None
    check_ceilings(exp, sched, ceilings)
    try:
        check_release_step(
            release_step,
            horizon=exp.horizon,
            with_release=exp.with_release,
            owner="this experiment",
        )
    except PolicyError as exc:
        raise SafetyViolation(str(exc)) from None
    return sched


def _check_can_add(session: Session, exp: Experiment, n: int) -> None:
    if exp.status != "active":
        raise Conflict(f"experiment {exp.id} is {exp.status}; set it active to add trials")
    if exp.budget is not None:
        used = session.scalar(
            select(func.count())
            .select_from(Trial)
            .where(
                Trial.experiment_id == exp.id,
                Trial.status != lc.ABANDONED,
                Trial.source != REFERENCE,  # drift checks are outside the budget
            )
        )
        if (used or 0) + n > exp.budget:
            raise Conflict(
                f"budget of {exp.budget} trials reached ({used} used, {n} more asked); "
                "raise it with PATCH /api/experiments/{id}"
            )


def _next_index(session: Session, exp: Experiment) -> int:
    last = session.scalar(select(func.max(Trial.index)).where(Trial.experiment_id == exp.id))
    return (last or 0) + 1


def _new_trial(
    session: Session,
    exp: Experiment,
    theta: Any,
    *,
    source: str,
    actor: Actor,
    index: int,
    note: str = "",
    predicted: tuple[float, float] | None = None,
    initial_status: str | None = None,
    ceilings: HardwareCeilings | None = None,
    suggestion_basis: dict[str, Any] | None = None,
) -> Trial:
    """Create a trial (proposed), then move it on: sim → queued, hardware → awaiting."""
    th, schedule, release = decode_checked(policy_of(exp), theta)
    check_ceilings(exp, schedule, ceilings)
    now = utcnow()
    trial = Trial(
        experiment_id=exp.id,
        index=index,
        status=lc.PROPOSED,
        status_reason="",
        source=source,
        note=note,
        theta=[float(v) for v in th],
        pressure_schedule_pa=np.asarray(schedule, dtype=np.float64).tolist(),
        release_step=release,
        predicted_mean=None if predicted is None else float(predicted[0]),
        predicted_std=None if predicted is None else float(predicted[1]),
        suggestion_basis=suggestion_basis,
        n_measurements=0,
        attempts=0,
        created_by=actor.username,
        created_at=now,
        updated_at=now,
    )
    session.add(trial)
    session.flush()
    record(
        session,
        actor=actor.username,
        action="trial.create",
        entity="trial",
        entity_id=trial.id,
        experiment_id=exp.id,
        trial_id=trial.id,
        after=lc.PROPOSED,
        detail={"source": source, "index": index},
        now=now,
    )
    nxt = initial_status or (lc.AWAITING_CONFIRMATION if exp.target == "hardware" else lc.QUEUED)
    if nxt != lc.PROPOSED:
        lc.transition(session, trial, nxt, actor=actor.username, now=now)
    return trial


@dataclass(frozen=True)
class OptimizerInputs:
    """What the optimiser is rebuilt from: a snapshot of the experiment's trials."""

    spec: OptimizerSpec
    observations: list[Observation]  # in trial index order
    pending: np.ndarray | None  # (k, dim)
    observed_ids: tuple[int, ...]  # trials behind ``observations`` (refused ones included)
    pending_ids: frozenset[int]  # trials behind ``pending``
    #: schedule hashes of abandoned trials: never suggested again
    refused_hashes: frozenset[str] = frozenset()
    #: the objective an abandoned trial counts as (below the worst seen), None before any
    #: measurement (then abandoned θ count as pending: taken, never to be suggested)
    refused_penalty: float | None = None
    refused_ids: tuple[int, ...] = ()

    @property
    def dim(self) -> int:
        """D, the length of θ."""
        return self.spec.dim


def refusal_penalty(values: list[float]) -> float | None:
    """What an abandoned trial counts as: the worst objective seen minus the objectives'
    spread (their magnitude when they are all equal), so the model learns the region was
    refused. None without any objective."""
    if not values:
        return None
    lo, hi = min(values), max(values)
    spread = hi - lo if hi > lo else max(abs(lo), 1.0)
    return lo - spread


def optimizer_inputs(session: Session, exp: Experiment) -> OptimizerInputs:
    """Completed trials with an objective (executed θ when reported), pending θ, and the
    abandoned trials (refused by an operator) as penalised observations."""
    trials = list(
        session.scalars(select(Trial).where(Trial.experiment_id == exp.id).order_by(Trial.index))
    )
    obs = []
    pending = []
    observed_ids: list[int] = []
    pending_ids: set[int] = set()
    refused: list[Trial] = []
    for t in trials:
        if t.status == lc.COMPLETED and t.objective is not None:
            observed_ids.append(t.id)
            theta = t.executed_theta if t.executed_theta is not None else t.theta
            obs.append(
                Observation(
                    tuple(float(v) for v in theta),
                    float(t.objective),
                    None if t.objective_sem is None else float(t.objective_sem),
                )
            )
        elif t.status in lc.PENDING or t.status == lc.COMPLETED:
            # Includes trials that ran but await the operator's measurement: θ taken, outcome
            # unknown.
            pending.append(t.theta)
            pending_ids.add(t.id)
        elif t.status == lc.ABANDONED:
            refused.append(t)
    penalty = refusal_penalty([o.value for o in obs])
    for t in refused:
        if penalty is None:
            pending.append(t.theta)
        else:
            obs.append(Observation(tuple(float(v) for v in t.theta), penalty, None))
    spec = with_prior(session, exp, optimizer_spec(exp))  # + the linked sim experiment's data
    return OptimizerInputs(
        spec=spec,
        observations=obs,
        pending=np.asarray(pending, dtype=np.float64).reshape(-1, spec.dim) if pending else None,
        observed_ids=tuple(observed_ids) + tuple(t.id for t in refused),
        pending_ids=frozenset(pending_ids),
        refused_hashes=frozenset(
            schedule_hash(t.pressure_schedule_pa, t.release_step) for t in refused
        ),
        refused_penalty=penalty if refused else None,
        refused_ids=tuple(t.id for t in refused),
    )


def rebuild_optimizer(inputs: OptimizerInputs) -> Optimizer:
    """build_optimizer + observe_many: the optimiser exactly as the database describes it."""
    opt = build_optimizer(inputs.spec)
    if inputs.observations:
        opt.observe_many(inputs.observations)
    return opt


def ask(
    inputs: OptimizerInputs,
    n: int,
    *,
    timings: dict[str, float] | None = None,
    on_fitted: Callable[[Any], None] | None = None,
    basis: dict[str, Any] | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(n, D) suggested θ, and the model's predicted mean/std there (None before a GP).

    ``timings`` (if given) accumulates ``optimizer_s``: the seconds spent in build_optimizer +
    observe_many + suggest, i.e. what the raw optimiser costs on this data. ``on_fitted``
    (if given) gets the optimiser after its suggestion (``app.service.compute`` keeps it).
    ``basis`` (if given) is filled with ``Optimizer.suggestion_basis()``: what the
    suggestion leaned on.
    """
    t0 = time.perf_counter()
    opt = rebuild_optimizer(inputs)
    thetas = np.asarray(opt.suggest(n, pending=inputs.pending), dtype=np.float64).reshape(n, -1)
    if timings is not None:
        timings["optimizer_s"] = timings.get("optimizer_s", 0.0) + time.perf_counter() - t0
    if basis is not None:
        basis.clear()
        basis.update(opt.suggestion_basis())
    mean = std = None
    # Predict only once the optimiser has a model (past its initial design): then the GP it
    # just fitted for the suggestion is reused and the prediction costs next to nothing.
    n_obs = len(inputs.observations)
    n_pending = 0 if inputs.pending is None else len(inputs.pending)
    initial_only = n_obs < 2 or n_obs + n_pending + n <= opt.n_initial
    if isinstance(opt, Surrogate) and not initial_only:
        try:
            mean, std = opt.predict(thetas)
        except (OptimError, ValueError, RuntimeError):
            mean = std = None
    if on_fitted is not None:
        on_fitted(opt)
    return thetas, mean, std


def ask_avoiding_refused(
    inputs: OptimizerInputs,
    policy: Policy,
    n: int,
    *,
    timings: dict[str, float] | None = None,
    ask_once: Callable[[OptimizerInputs, int], tuple[Any, Any, Any]] | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``ask`` (or ``ask_once(inputs, n)``: the server's, in a compute process), never
    returning a θ that decodes to an abandoned trial's schedule (nor two equal schedules in
    one batch): such θ are handed back to the optimiser as pending and
    it is asked again; after 3 rounds a seeded random θ with a new schedule takes the place.
    """
    if ask_once is None:

        def ask_once(inp: OptimizerInputs, k: int) -> tuple[Any, Any, Any]:
            return ask(inp, k, timings=timings)

    if not inputs.refused_hashes:
        return ask_once(inputs, n)

    def key(theta: np.ndarray) -> str:
        d = policy.decode(theta)
        return schedule_hash(d.pressure_schedule_pa, d.release_step)

    extra: list[np.ndarray] = []
    for _ in range(3):
        pend = inputs.pending
        if extra:
            more = np.asarray(extra, dtype=np.float64).reshape(-1, inputs.dim)
            pend = more if pend is None else np.concatenate([pend, more])
        thetas, mean, std = ask_once(replace(inputs, pending=pend), n)
        seen = set(inputs.refused_hashes)
        bad = []
        for i, th in enumerate(thetas):
            h = key(th)
            if h in seen:
                bad.append(i)
            seen.add(h)
        if not bad:
            return thetas, mean, std
        extra.extend(thetas[i] for i in bad)
    rng = np.random.default_rng([inputs.spec.seed, len(inputs.observations), len(extra)])
    for i in bad:
        for _ in range(10_000):
            th = rng.random(inputs.dim)
            if key(th) not in seen:
                break
        thetas[i] = th
        seen.add(key(th))
        if mean is not None and std is not None:
            mean[i] = std[i] = np.nan
    return thetas, mean, std


def suggest(
    db: Database,
    experiment_id: int,
    n: int,
    *,
    actor: Actor,
    timings: dict[str, float] | None = None,
    ceilings: HardwareCeilings | None = None,
    asker: Callable[[OptimizerInputs, int], tuple[Any, ...]] | None = None,
) -> list[TrialRead]:
    """Ask the optimiser for ``n`` trials given the completed and pending ones; store them.

    ``asker(inputs, n) -> (thetas, mean, std, optimizer_s[, basis])`` runs the optimiser (the
    server passes ``ComputeRunner``'s, bounded in time); by default ``ask`` in this thread.
    Each trial stores what its suggestion leaned on (``suggestion_basis``: the optimiser's
    ``suggestion_basis()``, its own step, and the linked sim experiment).

    The optimiser runs outside the write lock (a GP fit takes seconds; workers keep
    reporting meanwhile). Before storing, the data is compared with what the optimiser saw:
    a trial added meanwhile (another suggest or attach) always forces a recompute, so two
    suggestions never ignore each other; new observations force one for up to 3 rounds.
    """
    basis: dict[str, Any] = {}  # what the last suggestion leaned on (each ask replaces it)
    for attempt in range(8):
        with db.read() as s:
            exp = get_experiment(s, experiment_id)
            _check_can_add(s, exp, n)
            inputs = optimizer_inputs(s, exp)
            policy = policy_of(exp)

        def ask_once(inp: OptimizerInputs, k: int) -> tuple[Any, Any, Any]:
            if asker is None:
                return ask(inp, k, timings=timings, basis=basis)
            thetas, mean, std, opt_s, *more = asker(inp, k)
            basis.clear()
            basis.update(more[0] if more and more[0] else {})
            if timings is not None:
                timings["optimizer_s"] = timings.get("optimizer_s", 0.0) + opt_s
            return thetas, mean, std

        thetas, mean, std = ask_avoiding_refused(inputs, policy, n, ask_once=ask_once)
        with db.write() as s:
            exp = get_experiment(s, experiment_id, for_update=True)
            now = optimizer_inputs(s, exp)
            if not now.pending_ids <= inputs.pending_ids | set(inputs.observed_ids):
                continue  # someone added trials: their θ must count as pending
            if now.observed_ids != inputs.observed_ids and attempt < 3:
                continue
            _check_can_add(s, exp, n)
            index = _next_index(s, exp)
            references = plan_references(s, exp, n, actor=actor)
            trials = []
            for i in range(n):
                if references.before[i]:  # a drift check is due: the reference θ first
                    trials.append(
                        _new_trial(
                            s,
                            exp,
                            references.theta,
                            source=REFERENCE,
                            actor=actor,
                            index=index,
                            note=references.note,
                            ceilings=ceilings,
                        )
                    )
                    index += 1
                predicted = None
                if mean is not None and std is not None and np.isfinite(mean[i]):
                    predicted = (mean[i], std[i])
                trials.append(
                    _new_trial(
                        s,
                        exp,
                        thetas[i],
                        source="optimizer",
                        actor=actor,
                        index=index,
                        predicted=predicted,
                        ceilings=ceilings,
                        suggestion_basis=basis_of_trial(basis, i, exp),
                    )
                )
                index += 1
            touch(exp)
            s.flush()
            return [TrialRead.build(t, has_trajectory=False) for t in trials]
    raise Conflict("trials kept being added while the optimiser ran; try again")


def attach(
    session: Session,
    experiment_id: int,
    theta: list[float],
    *,
    note: str,
    actor: Actor,
    ceilings: HardwareCeilings | None = None,
) -> TrialRead:
    """Add a trial with an operator-chosen θ (checked like any other)."""
    exp = get_experiment(session, experiment_id, for_update=True)
    _check_can_add(session, exp, 1)
    predicted = None
    trial = _new_trial(
        session,
        exp,
        theta,
        source="operator",
        actor=actor,
        index=_next_index(session, exp),
        note=note,
        predicted=predicted,
        ceilings=ceilings,
    )
    touch(exp)
    session.flush()
    return TrialRead.build(trial, has_trajectory=False)


# --- status changes --------------------------------------------------------------------------
def active_lease(session: Session, trial_id: int) -> Lease | None:
    """The trial's active lease, if a worker holds one."""
    return session.scalar(select(Lease).where(Lease.trial_id == trial_id, Lease.status == "active"))


def _end_lease(session: Session, trial: Trial, status: str, *, actor: Actor, why: str) -> None:
    lease = active_lease(session, trial.id)
    if lease is None:
        return
    lease.status = status
    lease.ended_at = utcnow()
    record(
        session,
        actor=actor.username,
        action=f"lease.{status}",
        entity="lease",
        entity_id=lease.id,
        experiment_id=trial.experiment_id,
        trial_id=trial.id,
        before="active",
        after=status,
        detail={"why": why, "worker_id": lease.worker_id},
    )


def _end_by_operator(
    session: Session, trial_id: int, status: str, verb: str, reason: str, *, actor: Actor
) -> TrialRead:
    """Move a trial to ``status`` (failed/abandoned); a running one is aborted, lease revoked."""
    trial = get_trial(session, trial_id, for_update=True)
    was = trial.status
    lc.transition(
        session,
        trial,
        status,
        actor=actor.username,
        reason=reason,
        action="trial.abort" if was == lc.RUNNING else f"trial.{verb}",
    )
    if was == lc.RUNNING:
        _end_lease(session, trial, "revoked", actor=actor, why=f"trial {status}: {reason}")
    touch(trial.experiment)
    out = TrialRead.build(trial)
    session.flush()
    return out


def fail(session: Session, trial_id: int, reason: str, *, actor: Actor) -> TrialRead:
    """Mark a trial failed (an abort when it is running: its lease is revoked)."""
    return _end_by_operator(session, trial_id, lc.FAILED, "fail", reason, actor=actor)


def abandon(session: Session, trial_id: int, reason: str, *, actor: Actor) -> TrialRead:
    """Abandon a trial: never run, never suggested again (its lease, if any, is revoked)."""
    return _end_by_operator(session, trial_id, lc.ABANDONED, "abandon", reason, actor=actor)


def resolve(session: Session, trial_id: int, body: ResolveIn, *, actor: Actor) -> TrialRead:
    """A person's decision on a trial in needs_review (an override, audited).

    requeue: a sim trial goes back to queued; a hardware trial goes back to
    awaiting_confirmation and needs a fresh confirmation. complete: needs measurements.
    """
    trial = get_trial(session, trial_id, for_update=True)
    if trial.status != lc.NEEDS_REVIEW:
        raise lc.IllegalTransition(
            f"cannot resolve: trial #{trial.index} is {trial.status}, not needs_review",
            current=trial.status,
        )
    exp = trial.experiment
    detail = {"decision": body.decision}
    if body.decision == "requeue":
        if exp.target == "hardware":
            trial.confirmed_hash = trial.confirmed_by = None
            trial.confirmed_at = None
            new = lc.AWAITING_CONFIRMATION
        else:
            new = lc.QUEUED
    elif body.decision == "complete":
        if trial.objective is None:
            raise Conflict(
                f"cannot complete trial #{trial.index}: it has no measurement; post one first"
            )
        new = lc.COMPLETED
    elif body.decision == "fail":
        new = lc.FAILED
    else:
        new = lc.ABANDONED
    lc.transition(
        session,
        trial,
        new,
        actor=actor.username,
        reason=body.reason,
        action="trial.resolve",
        detail=detail,
    )
    touch(exp)
    out = TrialRead.build(trial)
    session.flush()
    return out


def check_previewed(session: Session, trial: Trial, current_hash: str, *, actor: Actor) -> None:
    """NotPreviewed unless ``actor`` ran a preview of exactly this schedule (hash) with the
    experiment's current command-hold setting."""
    hold = trial.experiment.command_hold
    previews = session.execute(
        select(Preview.schedule_hash, Preview.hold).where(
            Preview.trial_id == trial.id, Preview.previewed_by == actor.username
        )
    ).all()
    if any(h == current_hash and p_hold == hold for h, p_hold in previews):
        return
    if any(h == current_hash for h, _ in previews):
        why = "you previewed it with another command-hold setting"
    elif previews:
        why = "your preview was of a different schedule"
    else:
        why = "you have not previewed it"
    raise NotPreviewed(
        f"cannot confirm trial #{trial.index}: {why}; preview exactly "
        f"this schedule ({current_hash[:12]}…) in 3D, look at it, then confirm"
    )


def confirm(
    session: Session,
    trial_id: int,
    given_hash: str,
    *,
    actor: Actor,
    ceilings: HardwareCeilings | None = None,
) -> TrialRead:
    """An operator's go-ahead for exactly this schedule (hash), re-checked against the limits."""
    trial = lock_for(
        session,
        trial_id,
        target="hardware",
        source=lc.AWAITING_CONFIRMATION,
        dest=lc.QUEUED,
        action="confirm",
        other_target="only hardware trials are confirmed",
    )
    exp = trial.experiment
    current = schedule_hash(trial.pressure_schedule_pa, trial.release_step)
    if given_hash != current:
        raise ConfirmationMismatch(
            f"schedule_hash {given_hash[:12]}… is not trial #{trial.index}'s current schedule "
            f"({current[:12]}…); reload the trial and confirm what it will run"
        )
    check_schedule_safe(exp, trial.pressure_schedule_pa, trial.release_step, ceilings=ceilings)
    check_previewed(session, trial, current, actor=actor)
    now = utcnow()
    session.add(
        Confirmation(
            trial_id=trial.id, schedule_hash=current, confirmed_by=actor.username, confirmed_at=now
        )
    )
    trial.confirmed_hash = current
    trial.confirmed_by = actor.username
    trial.confirmed_at = now
    lc.transition(
        session,
        trial,
        lc.QUEUED,
        actor=actor.username,
        action="trial.confirm",
        detail={"schedule_hash": current},
        now=now,
    )
    touch(exp)
    out = TrialRead.build(trial)
    session.flush()
    return out
