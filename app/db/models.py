"""Tables: experiments, trials, sim twins, measurements, artifacts, users, tokens, leases,
confirmations, idempotency keys and the append-only audit log. Pressures in Pa, times UTC."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Integer,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.db.base import Base, UTCDateTime, utcnow
from app.policy import PressureLimits, policy_dim


class User(Base):
    """A person or a worker account. role: operator | viewer | worker."""

    __tablename__ = "users"

    id: Mapped[int] = mapped_column(primary_key=True)
    username: Mapped[str] = mapped_column(String(64), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    password_hash: Mapped[str | None] = mapped_column(String(256))
    disabled: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)

    tokens: Mapped[list[Token]] = relationship(back_populates="user")


class Token(Base):
    """An API token; only its SHA-256 hex digest is stored."""

    __tablename__ = "tokens"

    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    token_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    label: Mapped[str] = mapped_column(String(64), default="")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime)  # None: never

    user: Mapped[User] = relationship(back_populates="tokens")


class Experiment(Base):
    """One optimisation campaign: task, target, policy (P, H, release step), limits, optimiser."""

    __tablename__ = "experiments"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    task: Mapped[str] = mapped_column(String(32))
    target: Mapped[str] = mapped_column(String(16))
    sim_preset: Mapped[str] = mapped_column(String(32), default="reference")
    # how each schedule row is applied: "zero" (held each step) or "linear" (ramped from the
    # previous row, from zero at reset); a ramped schedule is a different motion
    command_hold: Mapped[str] = mapped_column(String(16), default="zero", server_default="zero")
    objective_unit: Mapped[str] = mapped_column(String(16))  # m | m/s | N | score
    # policy
    levels: Mapped[int] = mapped_column(Integer)
    horizon: Mapped[int] = mapped_column(Integer)
    with_release: Mapped[bool] = mapped_column(Boolean)
    # hardware limits (None: the simulator's full [0, 275.8 kPa] range)
    limits_nominal_pa: Mapped[list[float] | None] = mapped_column(JSON)
    limits_max_step_pa: Mapped[float | None] = mapped_column(Float)
    limits_source_pa: Mapped[float | None] = mapped_column(Float)
    # optimiser
    method: Mapped[str] = mapped_column(String(32))
    acquisition: Mapped[str | None] = mapped_column(String(32))  # None: the method's default
    kappa: Mapped[float | None] = mapped_column(Float)
    n_initial: Mapped[int] = mapped_column(Integer)
    seed: Mapped[int] = mapped_column(Integer)
    optimizer_settings: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    #: measurement sources the objective is made of, comma-separated (None: the default for
    #: task and target, ``app.service.schemas.objective_sources_of``)
    objective_sources: Mapped[str | None] = mapped_column(String(64))
    #: BO only: how fast the GP's trust in old data fades, in trials (None: all weigh the
    #: same); passed to the BO optimiser's settings as ``age_halflife_trials``
    age_halflife_trials: Mapped[float | None] = mapped_column(Float)
    # drift checks (app.service.drift): a reference θ every k hardware trials
    reference_every: Mapped[int | None] = mapped_column(Integer)  # k; None: no references
    reference_theta_from: Mapped[str | None] = mapped_column(String(16))  # incumbent | trial
    #: the trial whose θ the references repeat (chosen, or the incumbent once frozen)
    reference_trial_id: Mapped[int | None] = mapped_column(Integer)
    #: the θ every reference runs (None until the incumbent is frozen by the first reference)
    reference_theta: Mapped[list[float] | None] = mapped_column(JSON)
    #: the band is drawn from the first m scored references
    drift_baseline_n: Mapped[int] = mapped_column(Integer, default=3, server_default="3")
    #: the band's half-width in the objective's unit (None: 2 × the baseline's spread)
    drift_tolerance: Mapped[float | None] = mapped_column(Float)
    #: a sim experiment of the same task, policy (P, H, release) and command hold whose scored
    #: trials are this hardware experiment's sim prior (``app.service.sim_prior``); None: none
    sim_prior_experiment_id: Mapped[int | None] = mapped_column(ForeignKey("experiments.id"))
    # bookkeeping
    budget: Mapped[int | None] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(16), default="active")
    notes: Mapped[str] = mapped_column(Text, default="")
    version: Mapped[int] = mapped_column(Integer, default=1)
    created_by: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)

    trials: Mapped[list[Trial]] = relationship(back_populates="experiment", order_by="Trial.index")

    @property
    def limits(self) -> PressureLimits | None:
        """The hardware limits as one value, or None (the simulator's [0, 275.8 kPa] range)."""
        if self.limits_nominal_pa is None:
            return None
        assert self.limits_max_step_pa is not None and self.limits_source_pa is not None
        return PressureLimits(
            nominal_pa=tuple(self.limits_nominal_pa),
            max_step_pa=self.limits_max_step_pa,
            source_pa=self.limits_source_pa,
        )

    @property
    def dim(self) -> int:
        """D, the length of θ (``app.policy.policy_dim``)."""
        return policy_dim(self.horizon, self.with_release)


class Trial(Base):
    """One θ, its decoded pressure schedule, what was executed, and its status."""

    __tablename__ = "trials"
    __table_args__ = (UniqueConstraint("experiment_id", "index"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    experiment_id: Mapped[int] = mapped_column(
        ForeignKey("experiments.id", ondelete="CASCADE"), index=True
    )
    index: Mapped[int] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(32), index=True)
    status_reason: Mapped[str] = mapped_column(Text, default="")
    #: optimizer | operator | import | reference (a drift check: the experiment's reference θ
    #: again, scheduled every k hardware trials, app.service.drift)
    source: Mapped[str] = mapped_column(String(16))
    note: Mapped[str] = mapped_column(Text, default="")
    theta: Mapped[list[float]] = mapped_column(JSON)
    pressure_schedule_pa: Mapped[list[list[float]]] = mapped_column(JSON)
    release_step: Mapped[int | None] = mapped_column(Integer)
    executed_theta: Mapped[list[float] | None] = mapped_column(JSON)
    executed_pressure_schedule_pa: Mapped[list[list[float]] | None] = mapped_column(JSON)
    executed_release_step: Mapped[int | None] = mapped_column(Integer)
    objective: Mapped[float | None] = mapped_column(Float)
    objective_sem: Mapped[float | None] = mapped_column(Float)
    n_measurements: Mapped[int] = mapped_column(Integer, default=0)
    predicted_mean: Mapped[float | None] = mapped_column(Float)
    predicted_std: Mapped[float | None] = mapped_column(Float)
    #: what the optimiser's suggestion leaned on (``Optimizer.suggestion_basis()``: e.g. the
    #: model, how many hardware and sim-prior observations); None for other trials
    suggestion_basis: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    confirmed_hash: Mapped[str | None] = mapped_column(String(64))
    confirmed_by: Mapped[str | None] = mapped_column(String(64))
    confirmed_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    created_by: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime)

    experiment: Mapped[Experiment] = relationship(back_populates="trials")
    measurements: Mapped[list[Measurement]] = relationship(
        back_populates="trial", order_by="Measurement.id"
    )
    artifacts: Mapped[list[Artifact]] = relationship(back_populates="trial", order_by="Artifact.id")


class TrialTwin(Base):
    """A hardware trial's sim twin: a simulated run of exactly its schedule (``kind``
    "planned": before it runs, what the gate shows; "executed": what the robot ran), with the
    experiment's command hold and the sim prior's preset (``app.service.twins``)."""

    __tablename__ = "trial_twins"
    __table_args__ = (UniqueConstraint("trial_id", "kind"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trials.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(16))  # planned | executed
    schedule_hash: Mapped[str] = mapped_column(String(64))  # app.policy.schedule_hash
    sim_preset: Mapped[str] = mapped_column(String(32))
    command_hold: Mapped[str] = mapped_column(String(16))
    objective_rule: Mapped[str] = mapped_column(String(16))
    #: the linked sim experiment whose preset the twin used (None: the paper-matching default)
    sim_experiment_id: Mapped[int | None] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(16))  # done | error
    error: Mapped[str | None] = mapped_column(Text)
    predicted_objective: Mapped[float | None] = mapped_column(Float)
    predicted_tip_speed: Mapped[float | None] = mapped_column(Float)  # m/s
    bend_limit_hits: Mapped[list[int] | None] = mapped_column(JSON)  # joints 0..2
    wall_s: Mapped[float | None] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Measurement(Base):
    """One raw repeat of a trial's outcome (value in ``unit``), kept forever."""

    __tablename__ = "measurements"

    id: Mapped[int] = mapped_column(primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trials.id", ondelete="CASCADE"), index=True)
    value: Mapped[float] = mapped_column(Float)
    unit: Mapped[str] = mapped_column(String(16))
    note: Mapped[str] = mapped_column(Text, default="")
    source: Mapped[str] = mapped_column(String(16))  # tape | tracker | sim | imported
    created_by: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    # corrections: a repeat is never deleted; it is withdrawn (and maybe superseded) instead
    withdrawn_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    withdrawn_by: Mapped[str | None] = mapped_column(String(64))
    withdrawn_reason: Mapped[str | None] = mapped_column(Text)
    supersedes_id: Mapped[int | None] = mapped_column(ForeignKey("measurements.id"))

    trial: Mapped[Trial] = relationship(back_populates="measurements")


class Artifact(Base):
    """A file belonging to a trial (e.g. its trajectory .npz); path relative to artifacts_dir."""

    __tablename__ = "artifacts"

    id: Mapped[int] = mapped_column(primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trials.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(32))
    path: Mapped[str] = mapped_column(String(500))
    sha256: Mapped[str] = mapped_column(String(64))
    size_bytes: Mapped[int] = mapped_column(Integer)
    created_by: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)

    trial: Mapped[Trial] = relationship(back_populates="artifacts")


class Lease(Base):
    """A worker's claim on a trial, kept alive by heartbeats.

    status: active | completed | expired | revoked.
    """

    __tablename__ = "leases"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trials.id", ondelete="CASCADE"), index=True)
    worker_id: Mapped[str] = mapped_column(String(128))
    claimed_by: Mapped[str] = mapped_column(String(64))
    #: the worker's id for the claim that opened it (``ClaimIn.claim_id``): a retried claim
    #: gets its active leases back
    claim_id: Mapped[str | None] = mapped_column(String(64), index=True)
    status: Mapped[str] = mapped_column(String(16), index=True)
    attempt: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    heartbeat_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(UTCDateTime)
    ended_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    result_sha256: Mapped[str | None] = mapped_column(String(64))
    result_response: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class Confirmation(Base):
    """An operator's go-ahead for the exact schedule (by hash) of a hardware trial."""

    __tablename__ = "confirmations"

    id: Mapped[int] = mapped_column(primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trials.id", ondelete="CASCADE"), index=True)
    schedule_hash: Mapped[str] = mapped_column(String(64))
    confirmed_by: Mapped[str] = mapped_column(String(64))
    confirmed_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Preview(Base):
    """A sim preview of a trial's exact schedule that an operator ran to the end (what a
    confirmation must be bound to): who, when, the schedule's hash, the settings it ran with."""

    __tablename__ = "previews"

    id: Mapped[int] = mapped_column(primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trials.id", ondelete="CASCADE"), index=True)
    schedule_hash: Mapped[str] = mapped_column(String(64))
    #: the experiment's command hold the preview ran with (zero | linear)
    hold: Mapped[str | None] = mapped_column(String(64))
    sim_preset: Mapped[str] = mapped_column(String(32))
    job_id: Mapped[str] = mapped_column(String(32))
    predicted_objective: Mapped[float | None] = mapped_column(Float)
    previewed_by: Mapped[str] = mapped_column(String(64))
    previewed_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class IdempotencyKey(Base):
    """A write already applied under a client's ``Idempotency-Key`` (per scope)."""

    __tablename__ = "idempotency_keys"
    __table_args__ = (UniqueConstraint("scope", "key"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    scope: Mapped[str] = mapped_column(String(64))
    key: Mapped[str] = mapped_column(String(200))
    request_sha256: Mapped[str] = mapped_column(String(64))
    summary: Mapped[str] = mapped_column(Text, default="")
    #: the reply the write got (JSON), returned again with the 409 of a replayed request
    receipt: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    created_by: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class AuditLog(Base):
    """Append-only record of every state change: who, what, when, before → after."""

    __tablename__ = "audit_log"

    id: Mapped[int] = mapped_column(primary_key=True)
    at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow, index=True)
    actor: Mapped[str] = mapped_column(String(64))
    action: Mapped[str] = mapped_column(String(64))
    entity: Mapped[str] = mapped_column(String(32))
    entity_id: Mapped[str] = mapped_column(String(64))
    experiment_id: Mapped[int | None] = mapped_column(Integer, index=True)
    trial_id: Mapped[int | None] = mapped_column(Integer, index=True)
    before: Mapped[str | None] = mapped_column(Text)
    after: Mapped[str | None] = mapped_column(Text)
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON)
