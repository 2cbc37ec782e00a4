"""The stand-in robot with a reality gap: its own physical parameters, drawn per instance from
documented ranges around the simulator's; gap 0 is the stand-in as it was."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.policy import Policy, PressureLimits
from app.sim import ArmParams, rollout
from app.workers.drivers import DriverCommand, DriverError
from app.workers.drivers.standin import (
    GAP_FRICTION_PER_STIFFNESS,
    GAP_RANGES,
    GAP_TIP_LOAD_KG,
    StandinDriver,
    instance_params,
)
from app.workers.objective import tip_speed_from_tracking

LIMITS = PressureLimits()
POLICY = Policy(levels=5, limits=LIMITS)


def command(theta: np.ndarray) -> DriverCommand:
    schedule = POLICY.decode(theta).pressure_schedule_pa
    return DriverCommand(
        1, "tip_speed", schedule, None, POLICY.step_s, np.asarray(LIMITS.nominal_pa)
    )


def robot(**options: str) -> StandinDriver:
    opts = {"preset": "fast", "state_file": "", "fault_probability": "0"}
    return StandinDriver(**{**opts, "tracker_loss_probability": "0", **options})


def test_gap_zero_is_the_simulator_and_todays_standin():
    for instance in (0, 5):
        params, drawn = instance_params(0.0, instance)
        assert params == ArmParams() and drawn["nominal"]
    cmd = command(np.random.default_rng(1).random(POLICY.dim))
    today, zero = robot(seed="3"), robot(seed="3", gap="0", instance="9")
    for _ in range(2):  # drift on: the same robot trial after trial
        a, b = today.execute(cmd), zero.execute(cmd)
        np.testing.assert_array_equal(a.tracking.tip_vel_m_s, b.tracking.tip_vel_m_s)
        assert a.info == b.info and "gap" not in b.info


def _factors(params: ArmParams) -> dict[str, np.ndarray]:
    base = ArmParams()
    pairs = list(zip(params.joints, base.joints, strict=True))
    return {
        "stiffness": np.array([j.stiffness_nm_rad / b.stiffness_nm_rad for j, b in pairs]),
        "damping": np.array([j.damping_nms_rad / b.damping_nms_rad for j, b in pairs]),
        "time_constant": np.array([j.time_constant_s / b.time_constant_s for j, b in pairs]),
        "link_mass": np.array(
            [a.mass_kg / b.mass_kg for a, b in zip(params.links, base.links, strict=True)]
        ),
    }


@pytest.mark.parametrize("gap", [0.5, 1.0])
def test_a_gap_draws_a_seeded_instance_within_the_documented_ranges(gap):
    draws = [instance_params(gap, k)[0] for k in range(8)]
    assert instance_params(gap, 3)[0] == draws[3]  # the instance seed picks the robot
    assert len({p.joints[0].stiffness_nm_rad for p in draws}) == 8
    base = ArmParams()
    for p in draws:
        for name, f in _factors(p).items():
            assert np.all(np.abs(f - 1.0) <= gap * GAP_RANGES[name] + 1e-12), name
        assert 0.0 <= p.tip_load_kg <= gap * GAP_TIP_LOAD_KG
        for j, b in zip(p.joints, base.joints, strict=True):
            assert 0.0 <= j.frictionloss_nm <= gap * GAP_FRICTION_PER_STIFFNESS * b.stiffness_nm_rad
        assert dataclasses.replace(p, joints=base.joints, links=base.links, tip_load_kg=0.0) == base
    # the spread uses the ranges (not all draws huddle at the simulator)
    spread = np.concatenate([np.abs(_factors(p)["stiffness"] - 1.0) for p in draws])
    assert spread.max() > 0.6 * gap * GAP_RANGES["stiffness"]
    # a larger gap is the same robot further from the simulator
    f_half = _factors(instance_params(0.5, 2)[0])["damping"] - 1.0
    f_one = _factors(instance_params(1.0, 2)[0])["damping"] - 1.0
    np.testing.assert_allclose(f_one, 2.0 * f_half)


def test_gap_instances_differ_from_the_simulator_by_a_bounded_seeded_amount():
    cmd = command(np.random.default_rng(4).random(POLICY.dim))
    sim = rollout("tip_speed", cmd.pressure_schedule_pa, preset="fast").max_tip_speed
    quiet = {"bias_step_pa": "0", "stiffness_step": "0", "velocity_noise_m_s": "0"}
    speeds = []
    for instance in ("1", "2"):
        a = robot(seed="0", gap="1", instance=instance, **quiet).execute(cmd)
        b = robot(seed="8", gap="1", instance=instance, **quiet).execute(cmd)
        sa, sb = tip_speed_from_tracking(a.tracking), tip_speed_from_tracking(b.tracking)
        assert a.info["gap"]["instance"] == int(instance)
        assert abs(sa - sb) < 0.01 * sa  # the same robot, only the tracker's jitter differs
        speeds.append(sa)
    assert all(0.01 * sim < abs(s - sim) < 0.3 * sim for s in speeds), (sim, speeds)
    assert abs(speeds[0] - speeds[1]) > 0.005 * sim


def test_wear_lowers_the_stiffness_with_use_and_bad_gap_options_are_refused():
    worn = robot(seed="1", wear_per_trial="0.002")
    fresh = robot(seed="1")
    # the drift step each trial runs (a rollout each would only cost time here)
    a = [worn._advance_drift()[1] for _ in range(60)]
    b = [fresh._advance_drift()[1] for _ in range(60)]
    assert a[0] == b[0]  # no wear before the first trial
    assert np.mean(a[-10:]) < np.mean(b[-10:]) - 0.02
    with pytest.raises(DriverError, match="gap='3' must lie in"):
        robot(gap="3")
    with pytest.raises(DriverError, match="instance='x' is not an integer"):
        robot(instance="x")
