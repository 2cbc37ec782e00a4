"""Pydantic v2 schemas of what goes in and out of the service (the API's bodies and replies).

``*Create`` / ``*In`` validate input (finite numbers only, unknown fields refused);
``*Read`` are built from ORM rows.
"""

from __future__ import annotations

import re
from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, computed_field, field_validator

from app.db.models import AuditLog, Experiment, Trial
from app.optim.methods import DEFAULT_METHOD
from app.policy import N_CHAMBERS, CommandHold, TaskName, schedule_hash

DEFAULT_SOURCES = {"tip_speed": "tracker", "throw": "tape", "hammer": "tape"}


def default_objective_sources(task: str, target: str) -> list[str]:
    """The sources an objective is made of unless the experiment says otherwise: on hardware
    the tape (throw, hammer) or the tracker (tip speed); in simulation the simulator (and a
    value a script posts for a sim trial, as tape: a sim trial has one source or the other)."""
    if target == "sim":
        return ["sim", "tape", "imported"]
    return [DEFAULT_SOURCES[task], "imported"]


def objective_sources_of(exp: Experiment) -> list[str]:
    """The experiment's objective sources (its own, else the default for task and target)."""
    return sources_list(exp.objective_sources, exp.task, exp.target)


def sources_list(stored: str | None, task: str, target: str) -> list[str]:
    """A stored ``objective_sources`` (comma-separated, or None: the default) as a list."""
    if stored:
        return stored.split(",")
    return default_objective_sources(task, target)


#: key of ``ExperimentRead.build``'s counts that is not a status: reference trials not
#: abandoned (outside the budget)
REFERENCE_COUNT = "reference_trials"

Target = Literal["sim", "hardware"]
ExperimentStatus = Literal["active", "paused", "completed", "archived"]
Acquisition = Literal["logei", "ucb", "qlognei"]
Unit = Literal["m", "m/s", "N", "score"]
#: what measured a repeat: the operator's tape, the robot's tip tracker, the simulator, or an
#: imported observation
Source = Literal["tape", "tracker", "sim", "imported"]


# Control characters other than tab and newlines (NUL first: PostgreSQL cannot store it), and
# in names the invisible marks that reorder text on screen (bidi controls).
_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")
_BIDI = re.compile("[\u200e\u200f\u061c\u202a-\u202e\u2066-\u2069]")
_NAMES = frozenset({"name", "username", "worker_id", "unit", "sim_preset", "method"})


class _In(BaseModel):
    """Input: unknown fields refused, finite numbers only, strict types (a number is a
    number: ``"0.5"`` or ``false`` for one is refused, not converted), and text without
    control characters (names without bidi controls either)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)

    @field_validator("*", mode="after")
    @classmethod
    def _clean_text(cls, value: Any, info: ValidationInfo) -> Any:
        if isinstance(value, str) and info.field_name != "password":
            if _CONTROL.search(value):
                raise ValueError("control characters (such as NUL) are not allowed")
            if info.field_name in _NAMES and _BIDI.search(value):
                raise ValueError("bidirectional-text control characters are not allowed")
        return value


# --- experiments -----------------------------------------------------------------------------
class LimitsIn(_In):
    """Hardware pressure limits: nominal ± max step, within [0, source], Pa."""

    nominal_pa: float | list[float] = Field(
        100_000.0, description="12 nominal chamber pressures (or one for all), Pa"
    )
    max_step_pa: float = Field(30_000.0, gt=0, description="largest offset from nominal, Pa")
    source_pa: float = Field(205_000.0, gt=0, description="supply pressure, Pa")


ThetaFrom = Literal["incumbent", "trial"]


class ReferenceIn(_In):
    """A drift check: the reference θ run again every k hardware trials (``every`` = k ≥ 2:
    k − 1 ordinary trials, then a reference), its scores against a band."""

    every: int = Field(description="k: every k-th hardware trial is a reference (k ≥ 2)")
    theta_from: ThetaFrom = Field(
        "incumbent",
        description="incumbent: the best scored trial so far, frozen when the first reference "
        "is made; trial: the θ of the trial numbered trial_index",
    )
    trial_index: int | None = Field(
        None, ge=1, le=2**31 - 1, description="the trial's number (theta_from = trial)"
    )
    baseline_n: int = Field(
        3, ge=2, le=100, description="m: the band is drawn from the first m scored references"
    )
    tolerance: float | None = Field(
        None,
        gt=0,
        description="the band's half-width in the objective's unit; None: 2 × the baseline's "
        "spread (the larger of the first m references' std and their measurement SEM)",
    )


class ExperimentCreate(_In):
    """A new experiment. ``levels`` is P, ``horizon`` is H; ``with_release`` defaults to throw."""

    name: str = Field(min_length=1, max_length=200)
    task: TaskName
    target: Target = "sim"
    levels: int = Field(ge=2, le=1000, description="P, pressure levels per paired command")
    horizon: int = Field(10, ge=1, le=100, description="H, control steps over 5 s")
    with_release: bool | None = Field(None, description="release-step parameter (throw)")
    limits: LimitsIn | None = Field(None, description="required for hardware")
    method: str = Field(DEFAULT_METHOD, description="one of app.optim.METHODS")
    acquisition: Acquisition | None = Field(None, description="None: the method's default")
    kappa: float | None = Field(None, ge=0, le=1000, description="UCB κ (μ + √κ σ)")
    n_initial: int | None = Field(None, ge=2, le=10_000, description="random trials; D + 1")
    seed: int = Field(0, ge=0, le=2**31 - 1)
    optimizer_settings: dict[str, Any] = Field(default_factory=dict)
    budget: int | None = Field(None, ge=1, le=1_000_000, description="max trials")
    notes: str = Field("", max_length=20_000)
    sim_preset: str = Field("reference", max_length=32)
    command_hold: CommandHold = Field(
        "zero",
        description="zero: each row held for its step; linear: ramped from the previous row "
        "(from zero pressures at the start) over the step",
    )
    objective_unit: Unit | None = Field(
        None, description="unit of measurements; default m/s for tip_speed, else score"
    )
    objective_sources: list[Source] | None = Field(
        None,
        min_length=1,
        max_length=4,
        description="measurement sources the objective is made of; default: tape (throw, "
        "hammer on hardware), tracker (tip_speed on hardware), sim and tape (sim), and imported",
    )
    age_halflife_trials: float | None = Field(
        None,
        gt=0,
        le=1_000_000,
        description="BO only: the GP trusts older data less; an observation this many trials "
        "old carries extra noise as large as the data's spread, doubling (plus one) every such "
        "span after (None: all weigh the same)",
    )
    reference: ReferenceIn | None = Field(
        None, description="hardware only: a drift check (a reference θ every k trials)"
    )
    sim_prior_experiment_id: int | None = Field(
        None,
        ge=1,
        le=2**63 - 1,
        description="hardware only: a sim experiment of the same task, policy (P, H, release "
        "step) and command hold whose scored trials the optimiser also learns from (its sim "
        "prior); refused with what differs",
    )


class ExperimentPatch(_In):
    """Fields an operator may change after creation."""

    status: ExperimentStatus | None = None
    notes: str | None = Field(None, max_length=20_000)
    budget: int | None = Field(None, ge=1, le=1_000_000)
    age_halflife_trials: float | None = Field(
        None, gt=0, le=1_000_000, description="BO only; null: all observations weigh the same"
    )


class LimitsRead(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    nominal_pa: list[float]
    max_step_pa: float
    source_pa: float


class ReferenceRead(BaseModel):
    """An experiment's drift-check schedule."""

    every: int
    theta_from: str
    trial_id: int | None = Field(description="the trial whose θ the references repeat")
    theta: list[float] | None = Field(description="None until the incumbent is frozen")
    baseline_n: int
    tolerance: float | None


class ExperimentRead(BaseModel):
    """An experiment with its trial counts and best objective so far."""

    # the stored columns of an ``Experiment`` are read by attribute (``limits`` and ``dim``
    # are its properties); ``build`` adds the counts
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    task: str
    target: str
    sim_preset: str
    command_hold: str
    objective_unit: str
    objective_sources: list[str]
    levels: int
    horizon: int
    with_release: bool
    dim: int
    limits: LimitsRead | None
    method: str
    acquisition: str | None
    kappa: float | None
    n_initial: int
    seed: int
    optimizer_settings: dict[str, Any]
    budget: int | None
    status: str
    notes: str
    version: int
    created_by: str
    created_at: datetime
    updated_at: datetime
    n_trials: int = 0
    status_counts: dict[str, int] = Field(default_factory=dict)
    best_objective: float | None = None
    best_trial_id: int | None = None
    best_trial_index: int | None = None
    #: trials that ran and await a measurement from the objective's sources
    n_awaiting_measurement: int = 0
    #: trials that count against the budget (all but abandoned), and whether it is reached
    n_budget_used: int = 0
    budget_reached: bool = False
    age_halflife_trials: float | None = None
    reference: ReferenceRead | None = None
    #: reference trials (drift checks; not abandoned): they do not count against the budget
    n_reference_trials: int = 0
    #: the linked sim experiment (its sim prior; hardware only), None without one
    sim_prior_experiment_id: int | None = None

    @field_validator("objective_sources", mode="before")
    @classmethod
    def _sources(cls, value: Any, info: ValidationInfo) -> Any:
        """A row's stored sources (comma-separated; None: the default) as a list."""
        if value is None or isinstance(value, str):
            return sources_list(value, info.data["task"], info.data["target"])
        return value

    @classmethod
    def build(
        cls,
        exp: Experiment,
        *,
        status_counts: dict[str, int] | None = None,
        best: tuple[int, float] | tuple[int, float, int] | None = None,
    ) -> ExperimentRead:
        """``exp`` as the API shows it, with its trials' ``status_counts`` (status: count, plus
        ``awaiting_measurement`` and ``REFERENCE_COUNT``) and its ``best`` trial (id, objective,
        index)."""
        out = cls.model_validate(exp)
        counts = dict(status_counts or {})
        out.n_awaiting_measurement = counts.pop("awaiting_measurement", 0)
        out.n_reference_trials = counts.pop(REFERENCE_COUNT, 0)
        out.status_counts = counts
        out.n_trials = sum(counts.values())
        out.n_budget_used = (
            sum(v for k, v in counts.items() if k != "abandoned") - out.n_reference_trials
        )
        out.budget_reached = exp.budget is not None and out.n_budget_used >= exp.budget
        if exp.reference_every is not None:
            out.reference = ReferenceRead(
                every=exp.reference_every,
                theta_from=exp.reference_theta_from or "incumbent",
                trial_id=exp.reference_trial_id,
                theta=exp.reference_theta,
                baseline_n=exp.drift_baseline_n,
                tolerance=exp.drift_tolerance,
            )
        if best is not None:
            out.best_trial_id, out.best_objective = best[0], best[1]
            out.best_trial_index = best[2] if len(best) > 2 else None
        return out


class VersionRead(BaseModel):
    """A number that changes whenever anything in the experiment changes."""

    experiment_id: int
    version: int


# --- trials ----------------------------------------------------------------------------------
class SuggestIn(_In):
    n: int = Field(1, ge=1, le=100, description="how many trials to propose")


class AttachIn(_In):
    """A θ the operator chose (like Ax's attach_trial)."""

    theta: list[float] = Field(min_length=1, max_length=1001)
    note: str = Field("", max_length=2000)


class ReasonIn(_In):
    reason: str = Field(min_length=1, max_length=2000)


class ResolveIn(_In):
    """What a person decided for a trial in needs_review."""

    decision: Literal["requeue", "fail", "complete", "abandon"]
    reason: str = Field(min_length=1, max_length=2000)


class ConfirmIn(_In):
    schedule_hash: str = Field(min_length=64, max_length=64, pattern="^[0-9a-f]{64}$")


class RepeatIn(_In):
    """One raw repeat of a measurement."""

    value: float
    unit: Unit
    note: str = Field("", max_length=2000)
    source: Literal["tape", "tracker"] | None = Field(
        None, description="what measured it; default: the experiment's first objective source"
    )


class WithdrawIn(_In):
    """Withdraw a repeat (kept, no longer counted), with the operator's reason."""

    reason: str = Field(min_length=1, max_length=2000)


class SupersedeIn(_In):
    """Replace a repeat by a corrected value (the old one is kept, withdrawn), with a reason."""

    value: float
    unit: Unit
    note: str = Field("", max_length=2000)
    reason: str = Field(min_length=1, max_length=2000)


class MeasurementsIn(_In):
    repeats: list[RepeatIn] = Field(min_length=1, max_length=100)


class ObservationIn(_In):
    """A past observation to import (e.g. from simulation)."""

    theta: list[float] = Field(min_length=1, max_length=1001)
    objective: float
    objective_sem: float | None = Field(None, ge=0)
    unit: Unit | None = None
    note: str = Field("", max_length=2000)


class ImportIn(_In):
    observations: list[ObservationIn] = Field(min_length=1, max_length=10_000)


class MeasurementRead(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    trial_id: int
    value: float
    unit: str
    note: str
    source: str
    created_by: str
    created_at: datetime
    withdrawn_at: datetime | None = None
    withdrawn_by: str | None = None
    withdrawn_reason: str | None = None
    supersedes_id: int | None = None


class AuditRead(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    at: datetime
    actor: str
    action: str
    entity: str
    entity_id: str
    experiment_id: int | None
    trial_id: int | None
    before: str | None
    after: str | None
    detail: dict[str, Any] | None


class TrialRead(BaseModel):
    """A trial as the API shows it (see docs/ARCHITECTURE.md, "Trial JSON"): the stored
    columns of a ``Trial`` (read by attribute), its schedule's hash and its duration."""

    model_config = ConfigDict(
        from_attributes=True, json_schema_serialization_defaults_required=True
    )

    id: int
    experiment_id: int
    index: int
    status: str
    status_reason: str
    source: str
    note: str
    theta: list[float]
    pressure_schedule_pa: list[list[float]]
    release_step: int | None
    executed_theta: list[float] | None
    executed_pressure_schedule_pa: list[list[float]] | None
    executed_release_step: int | None
    objective: float | None
    objective_sem: float | None
    n_measurements: int
    predicted_mean: float | None
    predicted_std: float | None
    suggestion_basis: dict[str, Any] | None = Field(
        None,
        description="what the optimiser's suggestion leaned on (its model, how many hardware "
        "and sim-prior observations); None for a trial the optimiser did not suggest",
    )
    confirmed_hash: str | None
    confirmed_by: str | None
    confirmed_at: datetime | None
    attempts: int
    created_by: str
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    has_trajectory: bool = False

    @computed_field  # type: ignore[prop-decorator]
    @property
    def schedule_hash(self) -> str:
        """What an operator's confirmation binds (``app.policy.schedule_hash``)."""
        return schedule_hash(self.pressure_schedule_pa, self.release_step)

    @computed_field  # type: ignore[prop-decorator]
    @property
    def duration_s(self) -> float | None:
        """Seconds from start to finish, once both are known."""
        if self.started_at is None or self.finished_at is None:
            return None
        return (self.finished_at - self.started_at).total_seconds()

    @classmethod
    def build(cls, t: Trial, *, has_trajectory: bool | None = None) -> TrialRead:
        """``t`` as the API shows it; ``has_trajectory`` (None: look through its artifacts)
        saves loading them when the caller knows."""
        out = cls.model_validate(t)
        if has_trajectory is None:
            has_trajectory = any(a.kind == "trajectory" for a in t.artifacts)
        out.has_trajectory = has_trajectory
        return out


class MeasurementReceipt(BaseModel):
    """Reply to a measurement post: the repeats it stored and the trial's objective after it.

    The whole trial, with every repeat and its audit trail, is ``GET /api/trials/{id}``.
    """

    trial_id: int
    experiment_id: int
    status: str
    objective: float | None = Field(description="mean of every repeat of the trial")
    objective_sem: float | None = Field(description="standard error of that mean (n ≥ 2)")
    n_measurements: int
    stored: list[MeasurementRead] = Field(description="the repeats this post stored, in order")

    @classmethod
    def build(cls, trial: Any, stored: list[MeasurementRead]) -> MeasurementReceipt:
        """From a Trial (or any object with its id, status and objective fields)."""
        return cls(
            trial_id=trial.id,
            experiment_id=trial.experiment_id,
            status=trial.status,
            objective=trial.objective,
            objective_sem=trial.objective_sem,
            n_measurements=trial.n_measurements,
            stored=stored,
        )


class PreviewRead(BaseModel):
    """A finished preview of a trial's schedule: what a confirmation is bound to."""

    model_config = ConfigDict(from_attributes=True)

    schedule_hash: str
    hold: str | None
    sim_preset: str
    job_id: str
    predicted_objective: float | None
    previewed_by: str
    previewed_at: datetime


class TwinRead(BaseModel):
    """A hardware trial's sim twin: a simulated run of exactly its planned (``kind``
    "planned", before it runs) or executed schedule, with the experiment's command hold."""

    model_config = ConfigDict(from_attributes=True)

    trial_id: int
    kind: Literal["planned", "executed"]
    schedule_hash: str
    sim_preset: str
    command_hold: str
    objective_rule: str
    sim_experiment_id: int | None = Field(
        description="the linked sim experiment whose preset it used; None: the default"
    )
    status: Literal["done", "error"]
    error: str | None
    predicted_objective: float | None
    predicted_tip_speed: float | None = Field(description="the simulated peak tip speed, m/s")
    bend_limit_hits: list[int] | None = Field(description="joints (0..2) that hit a bend limit")
    wall_s: float | None
    created_at: datetime


class TrialDetail(TrialRead):
    """A trial with its raw measurements, its previews, its sim twins and its audit trail."""

    measurements: list[MeasurementRead]
    previews: list[PreviewRead] = Field(default_factory=list)
    twins: list[TwinRead] = Field(
        default_factory=list, description="hardware: its sim twins (planned, executed)"
    )
    audit: list[AuditRead]

    @classmethod
    def build_detail(
        cls, t: Trial, audit: list[AuditLog], previews: list[Any] | None = None
    ) -> TrialDetail:
        return cls(
            **dict(TrialRead.build(t)),
            measurements=[MeasurementRead.model_validate(m) for m in t.measurements],
            previews=[PreviewRead.model_validate(p) for p in previews or []],
            audit=[AuditRead.model_validate(a) for a in audit],
        )


# --- drift checks ----------------------------------------------------------------------------
class DriftPointRead(BaseModel):
    """One scored reference trial."""

    trial_id: int
    index: int
    objective: float
    objective_sem: float | None
    finished_at: datetime | None
    baseline: bool = Field(description="one of the first m references the band is drawn from")
    outside: bool = Field(description="beyond the band (never for a baseline point)")


class DriftBandRead(BaseModel):
    """centre ± half_width: where a reference's score is expected while the robot is as it was."""

    center: float
    half_width: float
    low: float
    high: float
    rule: str = Field(description="how the half-width was found, in words")


class DriftRead(BaseModel):
    """An experiment's drift check: the reference's scores over time and the band."""

    experiment_id: int
    objective_unit: str
    reference: ReferenceRead | None
    reference_trial_index: int | None = Field(description="the number of the θ's source trial")
    points: list[DriftPointRead]
    earlier: list[DriftPointRead] = Field(
        default_factory=list, description="scored references of an earlier reference θ"
    )
    band: DriftBandRead | None = Field(description="None until m references are scored")
    shifted: bool = Field(description="the latest scored reference is beyond the band")
    warning: str = Field("", description="what the operator is told when shifted")
    message: str = ""
    next_reference_in: int | None = Field(
        description="ordinary hardware trials still to come before the next reference"
    )


# --- model insight ---------------------------------------------------------------------------
class SliceRead(BaseModel):
    """The GP posterior along θ[dim] through the incumbent (others held fixed)."""

    dim: int
    theta: list[float]
    mean: list[float]
    std: list[float]


class ModelRead(BaseModel):
    experiment_id: int
    method: str
    n_observations: int
    lengthscales: list[float] | None
    incumbent_theta: list[float] | None
    incumbent_objective: float | None
    incumbent_trial_id: int | None
    incumbent_trial_index: int | None = Field(None, description="the trial's number (index)")
    slices: list[SliceRead]
    message: str = ""
    n_refused: int = Field(0, description="abandoned trials: never suggested again")
    refused_penalty: float | None = Field(
        None, description="the objective the model is told each abandoned trial scored"
    )


# --- sim prior and sim twins ----------------------------------------------------------------
class SimPriorLinkIn(_In):
    """Link a hardware experiment to a sim experiment of the same task, policy and hold."""

    sim_experiment_id: int = Field(ge=1, le=2**63 - 1)


class SimPriorStartIn(_In):
    """Start a sim prior: a new sim experiment like this hardware one, linked, its first
    trials queued for the sim workers."""

    n_trials: int = Field(24, ge=1, le=100, description="sim trials to queue now")
    sim_preset: str | None = Field(
        None, max_length=32, description="default: the paper-matching preset (fast)"
    )
    name: str | None = Field(None, min_length=1, max_length=200)


class SimPriorRead(BaseModel):
    """A hardware experiment's sim prior: the linked sim experiment and what it has scored."""

    experiment_id: int
    sim_experiment_id: int | None
    sim_experiment_name: str | None = None
    sim_preset: str | None = None
    n_scored: int = Field(0, description="sim trials with an objective: the prior's data")
    n_pending: int = Field(0, description="sim trials still to run")
    best_objective: float | None = None
    twin_preset: str = Field(description="the preset this experiment's sim twins run with")
    twin_objective_rule: str


class SimPriorStarted(BaseModel):
    experiment: ExperimentRead
    sim_experiment: ExperimentRead
    queued: list[TrialRead]


class TwinComparisonRead(BaseModel):
    """One hardware trial beside its sim twin: what the robot scored, what the twin predicted
    (of what the robot executed when it ran, else of the plan) and the difference."""

    trial_id: int
    index: int
    status: str
    objective: float | None
    objective_sem: float | None
    twin: TwinRead | None
    discrepancy: float | None = Field(description="hardware objective − twin's prediction")


# --- workers, leases, results ----------------------------------------------------------------
_CLAIM_ID = re.compile(r"[A-Za-z0-9_.:-]{1,64}")


class ClaimIn(_In):
    worker_id: str = Field(min_length=1, max_length=128)
    target: Target
    max_trials: int = Field(1, ge=1, le=64)
    claim_id: str | None = Field(
        None,
        description="the worker's id for this claim (1-64 letters, digits, '_', '.', ':' or "
        "'-'), the same on every retry of it: a retry whose first try was stored gets that "
        "try's leases back (still active ones), not new trials",
    )

    @field_validator("claim_id")
    @classmethod
    def _claim_id_is_a_token(cls, v: str | None) -> str | None:
        if v is not None and not _CLAIM_ID.fullmatch(v):
            raise ValueError(
                f"claim_id must be 1-64 letters, digits, '_', '.', ':' or '-', got {v[:80]!r}"
            )
        return v


class ClaimRead(BaseModel):
    lease_id: str
    trial: TrialRead
    experiment: ExperimentRead
    lease_expires_at: datetime
    twin: TwinRead | None = Field(
        None, description="hardware: the sim twin of the schedule about to run, if ready"
    )


class LeaseRead(BaseModel):
    """A lease after a heartbeat, read from the ``Lease`` row (``LeaseRead.model_validate``)."""

    model_config = ConfigDict(from_attributes=True)

    lease_id: str = Field(validation_alias="id")
    trial_id: int
    worker_id: str
    status: str
    attempt: int
    lease_expires_at: datetime = Field(validation_alias="expires_at")


class ResultIn(_In):
    """What a worker ran and measured for a leased trial."""

    lease_id: str = Field(min_length=1, max_length=36)
    executed_pressure_schedule_pa: list[list[float]] | None = None
    executed_release_step: int | None = Field(None, ge=1, le=1000)
    objective: float | None = None
    trajectory_npz_b64: str | None = Field(None, description="np.savez bytes, base64")
    fault: str | None = Field(None, max_length=2000)
    summary: dict[str, Any] | None = Field(None, description="e.g. RolloutResult.to_summary()")

    @field_validator("executed_pressure_schedule_pa")
    @classmethod
    def _rectangular(cls, rows: list[list[float]] | None) -> list[list[float]] | None:
        if rows is None:
            return None
        if not rows or len(rows) > 1000:
            raise ValueError(f"needs 1 to 1000 rows (control steps), got {len(rows)}")
        for i, row in enumerate(rows):
            if len(row) != N_CHAMBERS:
                raise ValueError(
                    f"row {i} has {len(row)} pressures; every row needs {N_CHAMBERS} (Pa)"
                )
        return rows


class ResultRead(BaseModel):
    lease_id: str
    trial: TrialRead


# --- previews --------------------------------------------------------------------------------
class PreviewJobRead(BaseModel):
    job_id: str
    trial_id: int
    status: Literal["queued", "running", "done", "error"]
    progress: float
    error: str | None = None
    predicted_tip_speed: float | None = None
    predicted_objective: float | None = None
    bend_limit_hits: list[int] | None = None
    schedule_hash: str
    trajectory: dict[str, Any] | None = None


# --- users -----------------------------------------------------------------------------------
class LoginIn(_In):
    username: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=1024)


class UserRead(BaseModel):
    username: str
    role: str


class LoginRead(BaseModel):
    token: str
    user: UserRead
