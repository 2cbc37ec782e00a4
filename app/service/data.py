"""An experiment's data in and out: export (CSV/JSON), import of past observations, and the
GP's view of it (lengthscales, incumbent, 1-D posterior slices)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.models import Measurement, Trial
from app.optim import OptimError, Surrogate
from app.service import lifecycle as lc
from app.service.auth import Actor
from app.service.drift import incumbent
from app.service.errors import InvalidInput
from app.service.experiments import executed_theta, get_experiment, read_experiment, touch
from app.service.measurements import check_value, store_measurement
from app.service.schemas import (
    ImportIn,
    MeasurementRead,
    ModelRead,
    SliceRead,
    TrialRead,
)
from app.service.trials import (
    _check_can_add,
    _new_trial,
    _next_index,
    list_trials,
    optimizer_inputs,
    rebuild_optimizer,
)


def export_json(session: Session, experiment_id: int) -> dict[str, Any]:
    """The experiment, its trials and every raw measurement, as JSON-able dicts."""
    exp = read_experiment(session, experiment_id)
    trials = list_trials(session, experiment_id)
    ms = session.scalars(
        select(Measurement)
        .join(Trial, Measurement.trial_id == Trial.id)
        .where(Trial.experiment_id == experiment_id)
        .order_by(Measurement.id)
    )
    return {
        "experiment": exp.model_dump(mode="json"),
        "trials": [t.model_dump(mode="json") for t in trials],
        "measurements": [MeasurementRead.model_validate(m).model_dump(mode="json") for m in ms],
    }


CSV_FIELDS = (
    "index",
    "id",
    "status",
    "status_reason",
    "source",
    "objective",
    "objective_sem",
    "n_measurements",
    "predicted_mean",
    "predicted_std",
    "release_step",
    "executed_release_step",
    "created_at",
    "finished_at",
)


#: after θ: who made the trial, who confirmed it (hardware) and when, and every raw repeat
CSV_TAIL = ("created_by", "confirmed_by", "confirmed_at", "repeats")


def export_csv(session: Session, experiment_id: int) -> str:
    """One row per trial: index, status, objective, SEM, θ (planned and executed), times, the
    experiment's command hold (how the schedule's rows were applied); then who made and
    confirmed it, and its raw repeats (``value unit source by who; ...``, a withdrawn one says
    so, with its reason)."""
    exp = get_experiment(session, experiment_id)
    dim = exp.dim
    trials = list_trials(session, experiment_id)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        [
            *CSV_FIELDS,
            *(f"theta_{i}" for i in range(dim)),
            *(f"executed_theta_{i}" for i in range(dim)),
            "command_hold",
            *CSV_TAIL,
        ]
    )
    repeats: dict[int, list[str]] = {}
    for m in session.scalars(
        select(Measurement)
        .join(Trial, Measurement.trial_id == Trial.id)
        .where(Trial.experiment_id == experiment_id)
        .order_by(Measurement.id)
    ):
        text = f"{m.value!r} {m.unit} {m.source} by {m.created_by}"
        if m.withdrawn_at is not None:
            text += f" (withdrawn by {m.withdrawn_by}: {m.withdrawn_reason})"
        repeats.setdefault(m.trial_id, []).append(text)
    for t in trials:
        d = t.model_dump(mode="json")
        row = ["" if d[f] is None else d[f] for f in CSV_FIELDS]
        ex: list[float] | list[str] = t.executed_theta or [""] * dim
        tail = ["" if d[f] is None else d[f] for f in CSV_TAIL[:-1]]
        w.writerow(
            [
                *row,
                *(repr(v) for v in t.theta),
                *(v if v == "" else repr(v) for v in ex),
                exp.command_hold,
                *tail,
                "; ".join(repeats.get(t.id, [])),
            ]
        )
    return buf.getvalue()


def import_observations(
    session: Session, experiment_id: int, body: ImportIn, *, actor: Actor
) -> list[TrialRead]:
    """Add past observations as completed trials (source ``import``), all or nothing."""
    exp = get_experiment(session, experiment_id, for_update=True)
    _check_can_add(session, exp, len(body.observations))
    index = _next_index(session, exp)
    out = []
    for i, ob in enumerate(body.observations):
        unit = ob.unit or exp.objective_unit
        check_value(ob.objective, unit, exp.objective_unit, what=f"observations[{i}].objective")
        try:
            trial = _new_trial(
                session,
                exp,
                ob.theta,
                source="import",
                actor=actor,
                index=index + i,
                note=ob.note,
                initial_status=lc.PROPOSED,
            )
        except InvalidInput as exc:
            raise InvalidInput(f"observations[{i}]: {exc}") from None
        trial.executed_pressure_schedule_pa = trial.pressure_schedule_pa
        trial.executed_release_step = trial.release_step
        trial.executed_theta = executed_theta(
            exp, trial.theta, trial.pressure_schedule_pa, trial.release_step
        )
        store_measurement(
            session,
            trial,
            [(ob.objective, unit, ob.note or "imported")],
            actor=actor,
            source="imported",
        )
        if ob.objective_sem is not None:
            trial.objective_sem = float(ob.objective_sem)
        lc.transition(session, trial, lc.QUEUED, actor=actor.username, action="trial.import")
        lc.transition(
            session,
            trial,
            lc.COMPLETED,
            actor=actor.username,
            reason="imported observation",
            action="trial.import",
        )
        out.append(trial)
    touch(exp)
    session.flush()
    return [TrialRead.build(t, has_trajectory=False) for t in out]


def model_insight(
    session: Session,
    experiment_id: int,
    *,
    n_points: int = 41,
    viewer: Callable[[Any, list[float], int], dict[str, Any]] | None = None,
) -> ModelRead:
    """Lengthscales, the incumbent and 1-D posterior slices through it (one per θ dim).

    ``viewer(inputs, incumbent, n_points) -> model_view's dict`` fits or reuses the model
    (the server passes ``ComputeRunner``'s, which reuses the suggestion's fit); by default
    the optimiser is rebuilt here."""
    exp = get_experiment(session, experiment_id)
    inputs = optimizer_inputs(session, exp)
    obs = inputs.observations
    n_penalised = len(inputs.refused_ids) if inputs.refused_penalty is not None else 0
    base: dict[str, Any] = {
        "experiment_id": exp.id,
        "method": exp.method,
        "n_observations": len(obs) - n_penalised,
        "n_refused": len(inputs.refused_ids),
        "refused_penalty": inputs.refused_penalty,
    }
    if not obs:
        return ModelRead(
            **base,
            lengthscales=None,
            incumbent_theta=None,
            incumbent_objective=None,
            incumbent_trial_id=None,
            slices=[],
            message="no completed trial with an objective yet",
        )
    best = incumbent(session, exp)
    assert best is not None
    theta = best.executed_theta if best.executed_theta is not None else best.theta
    inc = [float(v) for v in theta]
    head: dict[str, Any] = dict(
        base,
        incumbent_theta=inc,
        incumbent_objective=best.objective,
        incumbent_trial_id=best.id,
        incumbent_trial_index=best.index,
    )
    if viewer is None:
        view = model_view(rebuild_optimizer(inputs), inputs, inc, n_points)
    else:
        view = viewer(inputs, inc, n_points)
    return ModelRead(**head, **view)


def model_view(opt: Any, inputs: Any, incumbent: list[float], n_points: int) -> dict[str, Any]:
    """``{lengthscales, slices, message}`` of a fitted optimiser (the CPU-heavy part of
    ``model_insight``, run where the optimiser is)."""
    none: dict[str, Any] = {"lengthscales": None, "slices": []}
    if not isinstance(opt, Surrogate):
        return {**none, "message": f"{inputs.spec.method} has no surrogate model"}
    if len(inputs.observations) < 2:
        return {**none, "message": "the GP needs at least 2 observations"}
    try:
        ls = [float(v) for v in opt.lengthscales()]
        grid = np.linspace(0.0, 1.0, n_points)
        slices = []
        for d in range(inputs.dim):
            pts = np.tile(np.asarray(incumbent, dtype=np.float64), (n_points, 1))
            pts[:, d] = grid
            mean, std = opt.predict(pts)
            slices.append(
                SliceRead(
                    dim=d,
                    theta=grid.tolist(),
                    mean=[_finite(v) for v in mean],
                    std=[_finite(v) for v in std],
                )
            )
    except (OptimError, ValueError, RuntimeError) as exc:
        return {"lengthscales": None, "slices": [], "message": f"model unavailable: {exc}"}
    return {"lengthscales": ls, "slices": slices, "message": ""}


def _finite(v: float) -> float:
    v = float(v)
    return v if math.isfinite(v) else 0.0
