"""Workers' leases: claim (atomic, behind the safety gate), heartbeat, result, expiry sweep.

A hardware trial is claimable only when confirmed, when its current schedule still hashes to
the confirmed hash, and when that schedule passes the experiment's limits again. A sim trial
whose lease expires is requeued up to ``max_attempts`` claims, then failed; a hardware trial
whose lease expires goes to needs_review and is never rerun on its own.
"""

from __future__ import annotations

import hashlib
import json
import uuid
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import Experiment, Lease, Trial
from app.policy import HardwareCeilings, PolicyError, schedule_hash
from app.service import lifecycle as lc
from app.service.artifacts import store_trajectory
from app.service.audit import record
from app.service.auth import OPERATOR, Actor
from app.service.errors import (
    DuplicateRequest,
    Forbidden,
    InvalidInput,
    LeaseLost,
    NotFound,
    SafetyViolation,
)
from app.service.experiments import executed_theta, touch
from app.service.measurements import check_value, store_measurement
from app.service.schemas import ClaimIn, ClaimRead, ExperimentRead, LeaseRead, ResultIn, TrialRead
from app.service.trials import check_schedule_safe
from app.service.twins import twin_for_claim

SYSTEM_ACTOR = "system"


# --- expiry ----------------------------------------------------------------------------------
SERVICE_WORKER = "service"  # the worker_id of a run inside the server (app.service.runs)


def grant_restart_grace(
    session: Session, *, lease_seconds: float, now: datetime | None = None
) -> int:
    """At server start: give every active worker lease ``lease_seconds`` from now. Flushes.

    Leases run on wall-clock time, but a worker cannot heartbeat while the server is down; without
    this a slow restart would expire healthy leases and rerun (or, on hardware, hold for review)
    trials whose workers are still busy with them. A worker that really died still loses its
    lease ``lease_seconds`` after the restart. Runs inside a server (``SERVICE_WORKER``) get no
    grace: the process renewing them is gone unless another server still renews them.
    """
    now = now or utcnow()
    until = now + timedelta(seconds=lease_seconds)
    n = 0
    for lease in session.scalars(
        select(Lease).where(Lease.status == "active", Lease.worker_id != SERVICE_WORKER)
    ):
        if lease.expires_at < until:
            lease.expires_at = until
            n += 1
    session.flush()
    return n


def _expired_outcome(exp: Experiment, trial: Trial, why: str, max_attempts: int) -> tuple[str, str]:
    if exp.target == "hardware":
        return lc.NEEDS_REVIEW, f"{why}; a hardware trial is never rerun on its own"
    if trial.attempts < max_attempts:
        return lc.QUEUED, f"{why}; requeued (attempt {trial.attempts}/{max_attempts})"
    return lc.FAILED, f"{why}; {trial.attempts} attempts, giving up"


def sweep_expired(
    session: Session,
    *,
    max_attempts: int,
    now: datetime | None = None,
    orphan_after_s: float = 60.0,
) -> int:
    """Expire every active lease past its time; requeue/fail/needs_review its trial. Flushes.

    A sim trial run inside a server whose lease expired (the server died or stopped
    renewing it) fails with that reason. A trial ``running`` for ``orphan_after_s`` with no
    active lease at all (left by an older version, or by hand) fails (sim) or goes to
    needs_review (hardware) too: no trial stays running for ever. Returns the leases expired
    plus the orphans ended.
    """
    now = now or utcnow()
    leases = list(
        session.scalars(select(Lease).where(Lease.status == "active", Lease.expires_at < now))
    )
    for lease in leases:
        lease.status = "expired"
        lease.ended_at = now
        trial = session.get(Trial, lease.trial_id)
        assert trial is not None
        exp = trial.experiment
        record(
            session,
            actor=SYSTEM_ACTOR,
            action="lease.expired",
            entity="lease",
            entity_id=lease.id,
            experiment_id=trial.experiment_id,
            trial_id=trial.id,
            before="active",
            after="expired",
            detail={"worker_id": lease.worker_id, "expired_at": lease.expires_at.isoformat()},
            now=now,
        )
        if trial.status != lc.RUNNING:
            continue
        if lease.worker_id == SERVICE_WORKER:
            new, reason = (
                lc.FAILED,
                f"the server stopped while simulating it (service lease {lease.id} expired "
                "unrenewed); nothing was recorded",
            )
        else:
            why = f"worker {lease.worker_id} stopped heartbeating (lease {lease.id} expired)"
            new, reason = _expired_outcome(exp, trial, why, max_attempts)
        lc.transition(
            session,
            trial,
            new,
            actor=SYSTEM_ACTOR,
            reason=reason,
            action="trial.lease_expired",
            now=now,
        )
        touch(exp)
    has_lease = (
        select(Lease.id).where(Lease.trial_id == Trial.id, Lease.status == "active").exists()
    )
    orphans = list(
        session.scalars(
            select(Trial).where(
                Trial.status == lc.RUNNING,
                Trial.updated_at < now - timedelta(seconds=orphan_after_s),
                ~has_lease,
            )
        )
    )
    for trial in orphans:
        exp = trial.experiment
        why = f"running for over {orphan_after_s:g} s with no lease (nothing is running it)"
        if exp.target == "hardware":
            new, reason = lc.NEEDS_REVIEW, f"{why}; a person decides"
        else:
            new, reason = lc.FAILED, why
        lc.transition(
            session,
            trial,
            new,
            actor=SYSTEM_ACTOR,
            reason=reason,
            action="trial.orphan_swept",
            now=now,
        )
        touch(exp)
    session.flush()
    return len(leases) + len(orphans)


# --- claim -----------------------------------------------------------------------------------
def _gate(
    session: Session,
    exp: Experiment,
    trial: Trial,
    now: datetime,
    ceilings: HardwareCeilings | None = None,
) -> str | None:
    """Why this queued trial may not be handed to a worker (None: it may)."""
    try:
        check_schedule_safe(exp, trial.pressure_schedule_pa, trial.release_step, ceilings=ceilings)
    except SafetyViolation as exc:
        return str(exc)
    if exp.target == "hardware":
        if trial.confirmed_hash is None:
            return "hardware trial has no confirmation on record"
        current = schedule_hash(trial.pressure_schedule_pa, trial.release_step)
        if current != trial.confirmed_hash:
            return (
                f"schedule changed after confirmation (hash {current[:12]}… ≠ confirmed "
                f"{trial.confirmed_hash[:12]}…)"
            )
    return None


def open_lease(
    session: Session,
    trial: Trial,
    *,
    worker_id: str,
    actor: Actor,
    action: str,
    lease_seconds: float,
    now: datetime,
    claim_id: str | None = None,
) -> Lease:
    """The one way a trial starts running: one more attempt, queued → running (audited as
    ``action``, with a worker's id and the attempt; a run inside the server, ``SERVICE_WORKER``,
    records none), and an active lease held by ``worker_id`` for ``lease_seconds`` (flushed;
    the caller commits). ``claim_id``: the worker's claim that opened it, if it named one."""
    trial.attempts += 1
    worker = {"worker_id": worker_id, "attempt": trial.attempts}
    detail = None if worker_id == SERVICE_WORKER else worker
    lc.transition(
        session, trial, lc.RUNNING, actor=actor.username, action=action, detail=detail, now=now
    )
    lease = Lease(
        id=str(uuid.uuid4()),
        trial_id=trial.id,
        worker_id=worker_id,
        claimed_by=actor.username,
        claim_id=claim_id,
        status="active",
        attempt=trial.attempts,
        created_at=now,
        heartbeat_at=now,
        expires_at=now + timedelta(seconds=lease_seconds),
    )
    session.add(lease)
    touch(trial.experiment)
    session.flush()
    return lease


def claim(
    session: Session,
    body: ClaimIn,
    *,
    actor: Actor,
    lease_seconds: float,
    max_attempts: int,
    now: datetime | None = None,
    ceilings: HardwareCeilings | None = None,
) -> list[ClaimRead]:
    """Hand up to ``max_trials`` queued trials of ``target`` to a worker, each under a lease.

    Atomic: the caller's write session holds the write lock (SQLite) or row locks (SKIP
    LOCKED, PostgreSQL) from the first read, so no trial is handed out twice. ``now``: the
    clock (default: the wall clock), as for ``sweep_expired``.

    A claim that names a ``claim_id`` this worker (and account) already claimed under gets
    those leases back, the still-active ones, and nothing new: the retry of a claim whose
    answer was lost (a server killed after its commit) neither strands its trials until their
    leases expire nor takes more.
    """
    now = now or utcnow()
    sweep_expired(session, max_attempts=max_attempts, now=now)
    if body.claim_id is not None:
        earlier = session.scalars(
            select(Lease)
            .where(
                Lease.claim_id == body.claim_id,
                Lease.worker_id == body.worker_id,
                Lease.claimed_by == actor.username,
            )
            .order_by(Lease.trial_id)
        ).all()
        if earlier:
            return [
                _claim_read(session, lease, trial)
                for lease in earlier
                if lease.status == "active"
                and (trial := session.get(Trial, lease.trial_id)) is not None
            ]
    q = (
        select(Trial)
        .join(Experiment, Trial.experiment_id == Experiment.id)
        .where(
            Trial.status == lc.QUEUED,
            Experiment.target == body.target,
            Experiment.status == "active",
        )
        .order_by(Trial.updated_at, Trial.id)
        .limit(body.max_trials * 4 + 8)
        .with_for_update(skip_locked=True, of=Trial)
    )
    out: list[ClaimRead] = []
    for trial in session.scalars(q):
        if len(out) >= body.max_trials:
            break
        exp = trial.experiment
        refusal = _gate(session, exp, trial, now, ceilings)
        if refusal is not None:
            lc.transition(
                session,
                trial,
                lc.NEEDS_REVIEW,
                actor=SYSTEM_ACTOR,
                reason=f"refused by the safety gate: {refusal}",
                action="trial.gate_refused",
                now=now,
            )
            touch(exp)
            continue
        lease = open_lease(
            session,
            trial,
            worker_id=body.worker_id,
            actor=actor,
            action="trial.claim",
            lease_seconds=lease_seconds,
            now=now,
            claim_id=body.claim_id,
        )
        out.append(_claim_read(session, lease, trial))
    session.flush()
    return out


def _claim_read(session: Session, lease: Lease, trial: Trial) -> ClaimRead:
    exp = trial.experiment
    return ClaimRead(
        lease_id=lease.id,
        trial=TrialRead.build(trial, has_trajectory=False),
        experiment=ExperimentRead.build(exp),
        lease_expires_at=lease.expires_at,
        twin=twin_for_claim(session, trial.id) if exp.target == "hardware" else None,
    )


def _get_lease(session: Session, lease_id: str, actor: Actor) -> Lease:
    lease = session.get(Lease, lease_id)
    if lease is None:
        raise NotFound(f"lease {lease_id} not found")
    if actor.role != OPERATOR and lease.claimed_by != actor.username:
        raise Forbidden(f"lease {lease_id} belongs to {lease.claimed_by}, not {actor.username}")
    return lease


def _lost(lease: Lease, trial: Trial | None) -> LeaseLost:
    state = f"; trial {lease.trial_id} is now {trial.status}" if trial is not None else ""
    when = lease.ended_at.isoformat() if lease.ended_at else "?"
    return LeaseLost(
        f"lease {lease.id} was {lease.status} at {when}{state}; a late result or heartbeat "
        "for a lost lease is refused"
    )


def heartbeat(
    session: Session,
    lease_id: str,
    *,
    actor: Actor,
    lease_seconds: float,
    max_attempts: int,
    now: datetime | None = None,
) -> LeaseRead:
    """Extend an active lease by ``lease_seconds``. LeaseLost if it expired (what the sweep
    did is kept: LeaseLost keeps the transaction's changes). ``now``: the clock (default: the
    wall clock)."""
    now = now or utcnow()
    sweep_expired(session, max_attempts=max_attempts, now=now)
    lease = _get_lease(session, lease_id, actor)
    if lease.status != "active":
        raise _lost(lease, session.get(Trial, lease.trial_id))
    lease.heartbeat_at = now
    lease.expires_at = now + timedelta(seconds=lease_seconds)
    session.flush()
    return LeaseRead.model_validate(lease)


def _result_sha256(trial_id: int, body: ResultIn) -> str:
    blob = json.dumps({"trial_id": trial_id, **body.model_dump()}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def report_result(
    session: Session,
    trial_id: int,
    body: ResultIn,
    *,
    actor: Actor,
    artifacts_dir: Path,
    max_attempts: int,
    trajectory: bytes | None = None,
) -> dict[str, Any]:
    """Record what a worker executed and measured under its lease (idempotent per lease).

    The executed schedule gives the executed θ the GP is fitted on (``Policy.executed_theta``:
    the planned θ when the trial ran its plan). A fault sends a sim
    trial to failed and a hardware trial to needs_review; an executed schedule beyond the
    limits sends it to needs_review; otherwise an objective completes the trial.
    ``trajectory``: the body's ``trajectory_npz_b64`` decoded and checked by
    ``app.service.artifacts.decode_npz_b64`` before the write transaction began.
    """
    now = utcnow()
    sweep_expired(session, max_attempts=max_attempts, now=now)
    lease = _get_lease(session, body.lease_id, actor)
    if lease.trial_id != trial_id:
        raise InvalidInput(f"lease {lease.id} is for trial {lease.trial_id}, not {trial_id}")
    digest = _result_sha256(trial_id, body)
    if lease.status == "completed":
        if lease.result_sha256 == digest and lease.result_response is not None:
            session.flush()
            return dict(lease.result_response)
        raise DuplicateRequest(
            f"lease {lease.id} already has a different result recorded; nothing stored again"
        )
    trial = session.get(Trial, trial_id, with_for_update=True)
    if lease.status != "active" or trial is None:
        raise _lost(lease, trial)
    exp = trial.experiment
    # --- validate everything before storing anything
    exec_sched = body.executed_pressure_schedule_pa
    exec_release = body.executed_release_step
    # A fault with no executed schedule means nothing ran (e.g. the worker's own gate refused
    # it): record nothing as executed. Without a fault, no schedule means "ran as planned".
    ran = exec_sched is not None or not body.fault
    if exec_sched is None:
        exec_sched, exec_release = trial.pressure_schedule_pa, trial.release_step
    if not exp.with_release:
        exec_release = None
    try:
        exec_theta = executed_theta(exp, trial.theta, exec_sched, exec_release)
    except PolicyError as exc:
        raise InvalidInput(f"executed result: {exc}") from None
    if body.objective is not None:
        check_value(body.objective, exp.objective_unit, exp.objective_unit, what="objective")
    raw = trajectory
    if body.trajectory_npz_b64 is not None and raw is None:
        raise InvalidInput("the trajectory must be decoded (decode_npz_b64) before the lock")
    beyond = None
    try:
        check_schedule_safe(exp, exec_sched, exec_release)
    except SafetyViolation as exc:
        beyond = str(exc)
    # --- store
    if ran:
        trial.executed_pressure_schedule_pa = np.asarray(exec_sched, dtype=np.float64).tolist()
        trial.executed_release_step = exec_release
        trial.executed_theta = exec_theta
    if raw is not None:
        store_trajectory(session, artifacts_dir, trial, raw, actor=actor, tag=lease.id[:8])
    if body.objective is not None:
        note = f"worker {lease.worker_id}, lease {lease.id}"
        store_measurement(
            session,
            trial,
            [(body.objective, exp.objective_unit, note)],
            actor=actor,
            source="tracker" if exp.target == "hardware" else "sim",
        )
    detail: dict[str, Any] = {"lease_id": lease.id, "worker_id": lease.worker_id}
    if body.summary:
        detail["summary"] = body.summary
    if body.fault:
        if exp.target == "hardware":
            new, reason = lc.NEEDS_REVIEW, f"fault reported by the worker: {body.fault}"
        else:
            new, reason = lc.FAILED, f"fault reported by the worker: {body.fault}"
    elif beyond is not None:
        new, reason = lc.NEEDS_REVIEW, f"executed schedule beyond the limits: {beyond}"
    elif trial.objective is None and exp.target == "hardware" and exp.task != "tip_speed":
        # Throws and hits on the real robot are scored by a person with a tape measure.
        new, reason = lc.COMPLETED, "ran; awaiting the operator's measurement"
    elif trial.objective is None:
        new, reason = lc.NEEDS_REVIEW, "the worker reported no objective and no fault"
    else:
        new, reason = lc.COMPLETED, ""
    lc.transition(
        session,
        trial,
        new,
        actor=actor.username,
        reason=reason,
        action="trial.result",
        detail=detail,
        now=now,
    )
    lease.status = "completed"
    lease.ended_at = now
    session.flush()
    session.refresh(trial, attribute_names=["artifacts"])
    response = {"lease_id": lease.id, "trial": TrialRead.build(trial).model_dump(mode="json")}
    lease.result_sha256 = digest
    lease.result_response = response
    touch(exp)
    session.flush()
    return response
