"""A hardware experiment's sim prior: a linked sim experiment of the same task, policy
(P, H, release step and the pressure limits its levels span) and command hold, whose scored
trials the hardware optimiser also learns from (``app.optim.PriorData`` in its
``OptimizerSpec``).

Linking is refused, with every difference in the operator's words, unless the two
experiments describe the same motion: a prior from another task, another policy grid or
another command hold would teach the optimiser about different schedules. Sim trials live in
their own experiment, so they never count against the hardware experiment's budget.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.db.models import Experiment, Trial
from app.db.session import Database
from app.optim import OptimizerSpec, PriorData
from app.policy import SIM_MAX_PRESSURE_PA
from app.service import lifecycle as lc
from app.service.audit import record
from app.service.auth import Actor
from app.service.errors import Conflict, InvalidInput, NotFound
from app.service.experiments import create_experiment, get_experiment, read_experiment, touch
from app.service.schemas import (
    ExperimentCreate,
    ExperimentRead,
    LimitsIn,
    SimPriorRead,
    SimPriorStarted,
    SimPriorStartIn,
)

#: the preset a sim prior started from a hardware experiment, and a sim twin without a linked
#: sim experiment, run with: the paper-matching one (``app.bench.PAPER_PRESET``; tested equal)
DEFAULT_PRESET = "fast"
#: how twins score their run: the rule the sim workers and service runs use (rollout's default)
TWIN_OBJECTIVE_RULE = "paper"

_HOLD_WORDS = {"zero": "zero (each row held)", "linear": "linear (ramped)"}


def differences(hw: Experiment, sim: Experiment) -> list[str]:
    """What keeps ``sim`` from being ``hw``'s sim prior, in the operator's words (empty: none)."""
    out = []
    if hw.target != "hardware":
        out.append(f"experiment {hw.id} runs in simulation: only a hardware experiment has one")
    if sim.target != "sim":
        out.append(f"experiment {sim.id} runs on hardware, not in simulation")
    if hw.task != sim.task:
        out.append(f"the task differs ({hw.task} here, {sim.task} there)")
    if hw.levels != sim.levels:
        out.append(f"the pressure levels P differ ({hw.levels} here, {sim.levels} there)")
    if hw.horizon != sim.horizon:
        out.append(f"the control steps H differ ({hw.horizon} here, {sim.horizon} there)")
    if hw.with_release != sim.with_release:
        here, there = ("learned", "not") if hw.with_release else ("not", "learned")
        out.append(f"the release step differs ({here} here, {there} there)")
    if _limits(hw) != _limits(sim):
        out.append(
            f"the pressure limits differ ({_limits_words(hw)} here, {_limits_words(sim)} "
            "there: the same θ would be other pressures)"
        )
    if hw.command_hold != sim.command_hold:
        out.append(
            f"the command hold differs ({_HOLD_WORDS.get(hw.command_hold, hw.command_hold)} "
            f"here, {_HOLD_WORDS.get(sim.command_hold, sim.command_hold)} there)"
        )
    return out


def _limits(exp: Experiment) -> tuple[Any, ...] | None:
    """The limits θ's levels are spread over (rounded to 1 mPa), None: the simulator's range."""
    if exp.limits_nominal_pa is None:
        return None
    return (
        tuple(round(float(v), 3) for v in exp.limits_nominal_pa),
        round(float(exp.limits_max_step_pa or 0.0), 3),
        round(float(exp.limits_source_pa or 0.0), 3),
    )


def _limits_words(exp: Experiment) -> str:
    if exp.limits_nominal_pa is None:
        return f"the simulator's full range, 0 to {SIM_MAX_PRESSURE_PA / 1000:g} kPa"
    nominal = sorted({float(v) for v in exp.limits_nominal_pa})
    nom = (
        f"{nominal[0] / 1000:g}"
        if len(nominal) == 1
        else "/".join(f"{v / 1000:g}" for v in nominal)
    )
    step = float(exp.limits_max_step_pa or 0.0) / 1000
    source = float(exp.limits_source_pa or 0.0) / 1000
    return f"nominal {nom} kPa ± {step:g} kPa, source {source:g} kPa"


def check_linkable(hw: Experiment, sim: Experiment) -> None:
    """InvalidInput (422) naming every difference unless ``sim`` can be ``hw``'s sim prior."""
    diffs = differences(hw, sim)
    if diffs:
        raise InvalidInput(
            f"sim_prior_experiment_id: experiment {sim.id} cannot be the sim prior of "
            f"experiment {hw.id}: {'; '.join(diffs)}. A sim prior needs the same task, policy "
            "(P, H, release step) and command hold"
        )


def _linked(session: Session, hw: Experiment, sim_id: int | None, *, actor: Actor) -> None:
    before = hw.sim_prior_experiment_id
    if before == sim_id:
        return
    hw.sim_prior_experiment_id = sim_id
    record(
        session,
        actor=actor.username,
        action="experiment.sim_prior",
        entity="experiment",
        entity_id=hw.id,
        experiment_id=hw.id,
        before=None if before is None else str(before),
        after=None if sim_id is None else str(sim_id),
    )
    touch(hw)


def link(
    session: Session, experiment_id: int, sim_experiment_id: int, *, actor: Actor
) -> ExperimentRead:
    """Link (or relink) a hardware experiment to its sim prior (audited; flushed)."""
    hw = get_experiment(session, experiment_id, for_update=True)
    if sim_experiment_id == experiment_id:
        raise InvalidInput("sim_prior_experiment_id: an experiment cannot be its own sim prior")
    try:
        sim = get_experiment(session, sim_experiment_id)
    except NotFound:
        raise InvalidInput(
            f"sim_prior_experiment_id: there is no experiment {sim_experiment_id}"
        ) from None
    check_linkable(hw, sim)
    _linked(session, hw, sim.id, actor=actor)
    session.flush()
    return read_experiment(session, hw.id)


def unlink(session: Session, experiment_id: int, *, actor: Actor) -> ExperimentRead:
    """Drop the link (audited): later suggestions learn from hardware trials only."""
    hw = get_experiment(session, experiment_id, for_update=True)
    _linked(session, hw, None, actor=actor)
    session.flush()
    return read_experiment(session, hw.id)


def link_at_creation(
    session: Session, exp: Experiment, sim_experiment_id: int | None, *, actor: Actor
) -> None:
    """``ExperimentCreate.sim_prior_experiment_id``: checked like a later link."""
    if sim_experiment_id is not None:
        link(session, exp.id, sim_experiment_id, actor=actor)


# --- the prior the optimiser gets ----------------------------------------------------------------
def _scored(session: Session, sim_experiment_id: int) -> list[Trial]:
    return list(
        session.scalars(
            select(Trial)
            .where(
                Trial.experiment_id == sim_experiment_id,
                Trial.status == lc.COMPLETED,
                Trial.objective.is_not(None),
            )
            .order_by(Trial.index)
        )
    )


def prior_data(session: Session, exp: Experiment) -> PriorData | None:
    """The linked sim experiment's scored trials (executed θ, objective), or None without a
    link or before any of them is scored."""
    if exp.sim_prior_experiment_id is None:
        return None
    rows = _scored(session, exp.sim_prior_experiment_id)
    if not rows:
        return None
    theta = np.asarray(
        [t.executed_theta if t.executed_theta is not None else t.theta for t in rows],
        dtype=np.float64,
    )
    objective = np.asarray([float(t.objective) for t in rows if t.objective is not None])
    return PriorData(
        theta=theta, objective=objective, source=f"sim experiment {exp.sim_prior_experiment_id}"
    )


def with_prior(session: Session, exp: Experiment, spec: OptimizerSpec) -> OptimizerSpec:
    """``spec`` with the experiment's sim prior (unchanged without one)."""
    prior = prior_data(session, exp)
    return spec if prior is None else replace(spec, prior=prior)


def basis_of_trial(basis: dict[str, Any], i: int, exp: Experiment) -> dict[str, Any] | None:
    """What suggestion ``i`` of a batch leaned on, as the trial stores it: the optimiser's
    ``suggestion_basis()`` with this θ's own ``step`` ("prior", "design" or "model") in place
    of the batch's steps, and the linked sim experiment when the prior was used."""
    if not basis:
        return None
    out = {k: v for k, v in basis.items() if k != "steps"}
    steps = basis.get("steps") or []
    out["step"] = steps[i] if i < len(steps) else None
    out["sim_experiment_id"] = exp.sim_prior_experiment_id if out.get("mode") else None
    return out


# --- reading and starting --------------------------------------------------------------------
def read_sim_prior(session: Session, experiment_id: int) -> SimPriorRead:
    """The link and what the linked sim experiment has scored and still has to run."""
    exp = get_experiment(session, experiment_id)
    sim_id = exp.sim_prior_experiment_id
    base: dict[str, Any] = {
        "experiment_id": exp.id,
        "sim_experiment_id": sim_id,
        "twin_preset": twin_preset(session, exp),
        "twin_objective_rule": TWIN_OBJECTIVE_RULE,
    }
    if sim_id is None:
        return SimPriorRead(**base)
    sim = get_experiment(session, sim_id)
    scored = _scored(session, sim_id)
    pending = session.scalar(
        select(func.count())
        .select_from(Trial)
        .where(Trial.experiment_id == sim_id, Trial.status.in_(lc.PENDING))
    )
    return SimPriorRead(
        **base,
        sim_experiment_name=sim.name,
        sim_preset=sim.sim_preset,
        n_scored=len(scored),
        n_pending=int(pending or 0),
        best_objective=max(
            (float(t.objective) for t in scored if t.objective is not None), default=None
        ),
    )


def twin_preset(session: Session, exp: Experiment) -> str:
    """The preset a sim twin of ``exp``'s trials runs with: the linked sim experiment's, else
    the paper-matching default."""
    if exp.sim_prior_experiment_id is not None:
        sim = session.get(Experiment, exp.sim_prior_experiment_id)
        if sim is not None:
            return sim.sim_preset
    return DEFAULT_PRESET


def start(
    db: Database,
    experiment_id: int,
    body: SimPriorStartIn,
    *,
    actor: Actor,
    suggest: Callable[[int, int], list[Any]],
) -> SimPriorStarted:
    """Create a sim experiment like the hardware one (same task, policy and limits, hold,
    method and seed; the paper-matching preset unless told), link it, then queue
    ``n_trials`` sim trials for the sim workers through ``suggest(sim_experiment_id, n)``
    (the usual suggestion: its first ``n_trials`` are its initial design). The experiment
    and the link are stored in one transaction first; should the suggestion fail, the linked
    sim experiment is there without trials and its page's Suggest queues them."""
    with db.write() as s:
        hw = get_experiment(s, experiment_id, for_update=True)
        if hw.target != "hardware":
            raise InvalidInput(
                f"experiment {hw.id} runs in simulation: only a hardware experiment has a sim prior"
            )
        if hw.sim_prior_experiment_id is not None:
            raise Conflict(
                f"experiment {hw.id} already has sim experiment "
                f"{hw.sim_prior_experiment_id} as its sim prior; unlink it first"
            )
        spec = ExperimentCreate(
            name=body.name or f"{hw.name} · sim prior"[:200],
            task=hw.task,  # type: ignore[arg-type]
            target="sim",
            levels=hw.levels,
            horizon=hw.horizon,
            with_release=hw.with_release,
            method=hw.method,
            acquisition=hw.acquisition,  # type: ignore[arg-type]
            kappa=hw.kappa,
            n_initial=max(2, body.n_trials),
            seed=hw.seed,
            optimizer_settings=dict(hw.optimizer_settings or {}),
            limits=None
            if hw.limits_nominal_pa is None
            else LimitsIn(
                nominal_pa=[float(v) for v in hw.limits_nominal_pa],
                max_step_pa=float(hw.limits_max_step_pa or 0.0),
                source_pa=float(hw.limits_source_pa or 0.0),
            ),
            sim_preset=body.sim_preset or DEFAULT_PRESET,
            command_hold=hw.command_hold,  # type: ignore[arg-type]
            notes=f"sim prior of hardware experiment {hw.id} ({hw.name})",
        )
        sim = create_experiment(s, spec, actor=actor)
        _linked(s, hw, sim.id, actor=actor)
        s.flush()
        sim_id = sim.id
    queued = suggest(sim_id, body.n_trials)
    with db.read() as s:
        return SimPriorStarted(
            experiment=read_experiment(s, experiment_id),
            sim_experiment=read_experiment(s, sim_id),
            queued=queued,
        )
