"""Safety properties of the hardware worker's gate, over random and forged claims.

Every claim goes through `execute_claim` with a recording driver around the standin robot; the
recording log is the ground truth of what reached the "robot". The invariants are checked
against the claim as built, independently of the gate's code.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.policy import Policy, PressureLimits, schedule_hash
from app.workers.drivers import load_driver
from app.workers.drivers.recording import read_log
from app.workers.gate import SafetyRefusal, gate_hardware_trial
from app.workers.hardware import execute_claim

ROBOT_CEILING_PA = 205_000.0
ROBOT_MAX_STEP_PA = 30_000.0  # the standin's declared ceilings (HardwareCeilings)
FORGERIES = (
    "none",
    "beyond_limits",
    "stale_confirmation",
    "unconfirmed",
    "schedule_not_theta",
    "non_finite",
    "bad_release",
    "wrong_shape",
    "above_robot_ceiling",
    "above_robot_step",
    "sim_experiment",
)


@st.composite
def claims(draw: st.DrawFn, forgery: str) -> tuple[dict, dict]:
    """(claim, honest limits): a random claim for a hardware trial, forged the given way."""
    task = draw(st.sampled_from(["tip_speed", "throw", "hammer"]))
    levels = draw(st.integers(2, 7))
    horizon = draw(st.sampled_from([2, 5, 10]))
    max_step = draw(
        st.floats(30_500.0, 45_000.0)
        if forgery == "above_robot_step"  # limits wider than the driver's declared ceilings
        else st.floats(2_000.0, ROBOT_MAX_STEP_PA)
    )
    top = 275_000.0 if forgery == "above_robot_ceiling" else ROBOT_CEILING_PA
    nominal = draw(
        st.lists(st.floats(max_step, top - max_step), min_size=12, max_size=12)
        if forgery != "above_robot_ceiling"
        else st.just([top - max_step] * 12)
    )
    ceiling_case = forgery == "above_robot_ceiling"
    source = top if ceiling_case else draw(st.floats(min(max(nominal) + max_step, top), top))
    limits = PressureLimits(nominal_pa=tuple(nominal), max_step_pa=max_step, source_pa=source)
    policy = Policy(levels=levels, horizon=horizon, with_release=task == "throw", limits=limits)
    theta = np.array(draw(st.lists(st.floats(0.0, 1.0), min_size=policy.dim, max_size=policy.dim)))
    decoded = policy.decode(theta)
    schedule = decoded.pressure_schedule_pa.copy()
    release = decoded.release_step
    confirmed = schedule_hash(schedule, release)
    confirmed_by, confirmed_at = "ada", datetime.now(UTC).isoformat()
    experiment = {
        "id": 4,
        "target": "hardware",
        "task": task,
        "levels": levels,
        "horizon": horizon,
        "with_release": task == "throw",
        "limits": {"nominal_pa": list(nominal), "max_step_pa": max_step, "source_pa": source},
    }
    other_theta = (theta + draw(st.floats(0.05, 0.95))) % 1.0
    other = policy.decode(other_theta)

    if forgery == "beyond_limits":
        step = draw(st.integers(0, horizon - 1))
        chamber = draw(st.integers(0, 11))
        excess = draw(st.floats(5.0, 100_000.0))
        up = draw(st.booleans())
        schedule[step, chamber] = (
            limits.upper_pa[chamber] + excess if up else limits.lower_pa[chamber] - excess
        )
        confirmed = schedule_hash(schedule, release)  # the forger can hash too
    elif forgery == "stale_confirmation":
        if np.array_equal(other.pressure_schedule_pa, schedule):
            other_sched = schedule.copy()
            other_sched[0, 0] += 1.0
        else:
            other_sched = other.pressure_schedule_pa
        confirmed = schedule_hash(other_sched, release)
    elif forgery == "unconfirmed":
        which = draw(st.sampled_from(["hash", "by", "at"]))
        confirmed = None if which == "hash" else confirmed
        confirmed_by = None if which == "by" else confirmed_by
        confirmed_at = None if which == "at" else confirmed_at
    elif forgery == "schedule_not_theta":
        schedule = other.pressure_schedule_pa.copy()
        if np.array_equal(schedule, decoded.pressure_schedule_pa):
            schedule = np.flipud(schedule).copy()
            schedule[0] = np.asarray(nominal)  # on no level grid unless P is odd
            schedule[0, 0] += 0.5
        confirmed = schedule_hash(schedule, release)
    elif forgery == "non_finite":
        schedule[draw(st.integers(0, horizon - 1)), draw(st.integers(0, 11))] = draw(
            st.sampled_from([math.nan, math.inf, -math.inf])
        )
        confirmed = "0" * 64
    elif forgery == "bad_release":
        release = draw(st.sampled_from([0, horizon + 1, -1])) if task == "throw" else 1
        confirmed = schedule_hash(schedule, release)
    elif forgery == "wrong_shape":
        schedule = schedule[:, :11] if draw(st.booleans()) else np.vstack([schedule, schedule])
        confirmed = schedule_hash(schedule, release)
    elif forgery == "sim_experiment":
        experiment["target"] = "sim"

    trial = {
        "id": 17,
        "experiment_id": 4,
        "status": "running",
        "theta": theta.tolist(),
        "pressure_schedule_pa": schedule.tolist(),
        "release_step": release,
        "schedule_hash": "f" * 64,  # the server's field is not trusted by the gate
        "confirmed_hash": confirmed,
        "confirmed_by": confirmed_by,
        "confirmed_at": confirmed_at,
    }
    claim = {"lease_id": 99, "trial": trial, "experiment": experiment}
    return claim, {"lower": limits.lower_pa, "upper": limits.upper_pa, "source": source}


@pytest.mark.parametrize("forgery", FORGERIES)
def test_nothing_unconfirmed_stale_or_beyond_limits_reaches_the_driver(tmp_path, forgery):
    """Run `check_claim` on many random claims forged one way (or honest, for "none")."""

    @settings(
        max_examples=25 if forgery == "none" else 15,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow],
    )
    @given(case=claims(forgery))
    def check(case: tuple[dict, dict]) -> None:
        check_claim(tmp_path, forgery, *case)

    check()


def check_claim(tmp_path, forgery: str, claim: dict, honest: dict) -> None:
    """Gate and run one claim; assert what reached the driver, from the recording log."""
    log = tmp_path / f"cmds-{abs(hash(str(claim))) % 10**9}.jsonl"
    driver = load_driver(
        "recording",
        inner="standin",
        log=str(log),
        **{
            "inner.preset": "fast",
            "inner.state_file": "",
            "inner.fault_probability": "0",
            "inner.tracker_loss_probability": "0",
        },
    )
    outcome = execute_claim(driver, claim)
    reached = read_log(log)
    trial = claim["trial"]

    for entry in reached:  # the invariants, whatever the gate's code does
        sent = np.asarray(entry["pressure_schedule_pa"])
        assert np.all(np.isfinite(sent))
        assert np.all(sent >= np.maximum(honest["lower"], 0.0) - 1e-6)
        assert np.all(sent <= np.minimum(honest["upper"], honest["source"]) + 1e-6)
        assert sent.max() <= ROBOT_CEILING_PA
        nominal = np.asarray(claim["experiment"]["limits"]["nominal_pa"])
        assert np.all(np.abs(sent - nominal) <= ROBOT_MAX_STEP_PA + 1e-6)
        assert trial["confirmed_by"] and trial["confirmed_at"]
        assert schedule_hash(sent, entry["release_step"]) == trial["confirmed_hash"]
        np.testing.assert_array_equal(sent, np.asarray(trial["pressure_schedule_pa"]))

    if forgery == "none":
        assert len(reached) == 1, outcome.payload["fault"]
        assert outcome.payload["fault"] is None
        np.testing.assert_array_equal(
            outcome.payload["executed_pressure_schedule_pa"], trial["pressure_schedule_pa"]
        )
    else:
        assert reached == []
        assert outcome.payload["fault"].startswith("refused by the hardware worker: ")
        assert outcome.payload["executed_pressure_schedule_pa"] is None
        assert outcome.payload["objective"] is None


def test_unknown_command_hold_is_refused_and_a_known_one_reaches_the_driver():
    claim, _ = claims(forgery="none").example()
    trial, experiment = claim["trial"], claim["experiment"]
    command = gate_hardware_trial(trial, {**experiment, "command_hold": "linear"})
    assert command.command_hold == "linear"
    assert gate_hardware_trial(trial, experiment).command_hold == "zero"  # older servers
    with pytest.raises(SafetyRefusal, match="unknown command hold 'cubic'"):
        gate_hardware_trial(trial, {**experiment, "command_hold": "cubic"})


def test_the_gate_log_puts_the_twin_beside_the_gp():
    from app.workers.gate import predictions_line

    twin = {
        "status": "done",
        "sim_preset": "fast",
        "command_hold": "linear",
        "predicted_objective": 1.4866,
        "predicted_tip_speed": 1.4866,
        "bend_limit_hits": [0, 2],
    }
    trial = {"predicted_mean": 1.2, "predicted_std": 0.31}
    line = predictions_line({"trial": trial, "twin": twin})
    assert line == (
        "GP predicts 1.2 ± 0.31; sim twin (fast, linear hold) predicts 1.487, tip speed 1.49 "
        "m/s, bend limit hit at joint 0, 2"
    )
    assert predictions_line({"trial": {"predicted_mean": None}}) == (
        "no GP prediction; no sim twin yet"
    )
    failed = {"status": "error", "error": "simulation diverged"}
    assert predictions_line({"trial": trial, "twin": failed}).endswith(
        "sim twin failed: simulation diverged"
    )
