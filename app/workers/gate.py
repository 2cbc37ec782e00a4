"""The hardware worker's own safety gate: the last check before anything moves.

The server already refuses out-of-limit schedules and unconfirmed claims; this gate checks again
on the worker, from the claim's JSON alone, so that a server bug, a forged response or a changed
schedule still cannot reach the driver. Every check must pass or nothing is sent.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from app.policy import (
    COMMAND_HOLDS,
    N_CHAMBERS,
    TASKS,
    HardwareCeilings,
    Policy,
    PolicyError,
    PressureLimits,
    check_release_step,
    schedule_hash,
)
from app.workers.drivers.base import DriverCommand


class SafetyRefusal(Exception):
    """The worker refuses to run a trial; the message says which check failed."""


def limits_from_experiment(experiment: Mapping[str, Any]) -> PressureLimits:
    """The experiment's hardware limits (nominal ± max step within [0, source]); refuse if none."""
    limits = experiment.get("limits")
    if not isinstance(limits, Mapping) or any(
        limits.get(k) is None for k in ("nominal_pa", "max_step_pa", "source_pa")
    ):
        raise SafetyRefusal("experiment carries no hardware limits (nominal, max step, source)")
    try:
        return PressureLimits(
            nominal_pa=tuple(
                np.broadcast_to(np.asarray(limits["nominal_pa"], dtype=float), (N_CHAMBERS,))
            ),
            max_step_pa=float(limits["max_step_pa"]),
            source_pa=float(limits["source_pa"]),
        )
    except (PolicyError, ValueError, TypeError) as exc:
        raise SafetyRefusal(f"experiment's hardware limits are invalid: {exc}") from None


def policy_from_experiment(experiment: Mapping[str, Any]) -> Policy:
    """The experiment's policy (P, H, release step) with its hardware limits."""
    limits = limits_from_experiment(experiment)
    try:
        return Policy(
            levels=int(experiment["levels"]),
            horizon=int(experiment["horizon"]),
            with_release=bool(experiment.get("with_release") or False),
            limits=limits,
        )
    except (KeyError, PolicyError, TypeError, ValueError) as exc:
        raise SafetyRefusal(f"experiment's policy settings are invalid: {exc}") from None


def gate_hardware_trial(
    trial: Mapping[str, Any],
    experiment: Mapping[str, Any],
    *,
    trial_id: int | None = None,
    robot_max_pa: float | None = None,
    robot_ceilings: HardwareCeilings | None = None,
) -> DriverCommand:
    """Check a claimed hardware trial end to end; return the one command the driver may run.

    Checks, in order: the experiment targets hardware and owns the trial; the schedule is
    (H, 12), finite and inside nominal ± max step within [0, source]; the release step fits the
    policy; θ decodes to exactly this schedule; a confirmation (who, when, hash) is on record and
    its hash equals `schedule_hash` of the schedule about to be sent. `robot_max_pa` (the
    driver's own ceiling, independent of anything the server says) caps every chamber too, and
    `robot_ceilings` (the driver's declared source, maximum step and chamber maximum) bound both
    the experiment's limits and the schedule.

    Raises:
        SafetyRefusal: naming the first check that failed.
    """
    if experiment.get("target") != "hardware":
        raise SafetyRefusal(f"experiment target is {experiment.get('target')!r}, not 'hardware'")
    if trial.get("experiment_id") != experiment.get("id"):
        raise SafetyRefusal(
            f"trial belongs to experiment {trial.get('experiment_id')!r}, "
            f"claim came with experiment {experiment.get('id')!r}"
        )
    task = experiment.get("task")
    if task not in TASKS:
        raise SafetyRefusal(f"unknown task {task!r}")
    policy = policy_from_experiment(experiment)
    assert policy.limits is not None

    raw = trial.get("pressure_schedule_pa")
    if raw is None:
        raise SafetyRefusal("trial has no pressure schedule")
    try:
        schedule = policy.check(np.asarray(raw, dtype=np.float64))
    except (PolicyError, TypeError, ValueError) as exc:
        raise SafetyRefusal(f"schedule refused by the hardware limits: {exc}") from None
    if robot_max_pa is not None and float(schedule.max()) > robot_max_pa:
        raise SafetyRefusal(
            f"schedule peaks at {float(schedule.max()):.1f} Pa, above the robot's own ceiling "
            f"of {robot_max_pa:.1f} Pa"
        )

    if robot_ceilings is not None:
        try:
            robot_ceilings.check_limits(policy.limits)
            robot_ceilings.check_schedule(schedule, np.asarray(policy.limits.nominal_pa))
        except PolicyError as exc:
            raise SafetyRefusal(f"beyond the robot's own ceilings: {exc}") from None

    release = trial.get("release_step")
    try:
        check_release_step(release, horizon=policy.horizon, with_release=policy.with_release)
    except PolicyError as exc:
        raise SafetyRefusal(str(exc)) from None

    try:
        decoded = policy.decode(np.asarray(trial.get("theta"), dtype=np.float64))
    except (PolicyError, TypeError, ValueError) as exc:
        raise SafetyRefusal(f"trial θ is invalid: {exc}") from None
    if not np.allclose(decoded.pressure_schedule_pa, schedule, rtol=0.0, atol=1e-3) or (
        decoded.release_step != release
    ):
        raise SafetyRefusal("trial's schedule is not what its θ decodes to")

    # The server's own `schedule_hash` field is ignored: the worker hashes what it will send.
    confirmed_hash = trial.get("confirmed_hash")
    if not confirmed_hash or not trial.get("confirmed_by") or not trial.get("confirmed_at"):
        raise SafetyRefusal("no operator confirmation on record for this trial")
    expected = schedule_hash(schedule, release)
    if confirmed_hash != expected:
        raise SafetyRefusal(
            "confirmation is stale: it was given for a different schedule "
            f"(confirmed {str(confirmed_hash)[:12]}…, about to send {expected[:12]}…)"
        )

    hold = experiment.get("command_hold") or "zero"
    if hold not in COMMAND_HOLDS:
        known = " and ".join(COMMAND_HOLDS)
        raise SafetyRefusal(f"unknown command hold {hold!r}; this worker knows {known}")

    return DriverCommand(
        trial_id=int(trial_id if trial_id is not None else trial.get("id", -1)),
        task=str(task),
        pressure_schedule_pa=schedule.copy(),
        release_step=release,
        step_s=policy.step_s,
        nominal_pa=np.asarray(policy.limits.nominal_pa, dtype=np.float64),
        command_hold=str(hold),
    )


def predictions_line(claim: Mapping[str, Any]) -> str:
    """What the GP and the sim twin predict for a claimed trial, side by side, for the
    worker's log at the gate (informative only: neither is a safety check)."""
    trial = claim.get("trial") or {}
    mean, std = trial.get("predicted_mean"), trial.get("predicted_std")
    gp = "no GP prediction" if mean is None else f"GP predicts {mean:.4g} ± {std or 0.0:.2g}"
    twin = claim.get("twin")
    if not twin:
        return f"{gp}; no sim twin yet"
    if twin.get("status") != "done":
        return f"{gp}; sim twin failed: {twin.get('error')}"
    hits = twin.get("bend_limit_hits") or []
    bends = f"bend limit hit at joint {', '.join(map(str, hits))}" if hits else "no bend limit hit"
    return (
        f"{gp}; sim twin ({twin.get('sim_preset')}, {twin.get('command_hold')} hold) predicts "
        f"{twin.get('predicted_objective'):.4g}, tip speed {twin.get('predicted_tip_speed'):.3g} "
        f"m/s, {bends}"
    )
