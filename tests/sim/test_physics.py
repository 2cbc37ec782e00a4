"""Physics sanity of the simulated arm: real MuJoCo episodes (mostly the `fast` preset)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from app.policy import SIM_MAX_PRESSURE_PA
from app.sim import ArmParams, SimulationDiverged, rollout

P_MAX = SIM_MAX_PRESSURE_PA  # 40 psi
NO_GRAVITY = ArmParams(gravity_m_s2=(0.0, 0.0, 0.0))


def constant_schedule(pressures: dict[int, float], horizon: int = 10) -> np.ndarray:
    """(H, 12) schedule holding the given chamber pressures (Pa), all others at zero."""
    schedule = np.zeros((horizon, 12))
    for chamber, p in pressures.items():
        schedule[:, chamber] = p
    return schedule


def bang_bang(horizon: int = 10, phase: int = 0) -> np.ndarray:
    """Each pair flips between its extremes every step: the hardest swing the ranges allow."""
    schedule = np.zeros((horizon, 12))
    for t in range(horizon):
        plus = (t + phase) % 2 == 0
        schedule[t, 0::2] = P_MAX if plus else 0.0
        schedule[t, 1::2] = 0.0 if plus else P_MAX
    return schedule


@pytest.mark.parametrize(("joint", "axis", "dp"), [(0, 0, 100e3), (1, 1, 150e3), (2, 0, 60e3)])
def test_steady_pressure_difference_bends_joint_to_torque_over_stiffness(joint, axis, dp) -> None:
    """Gravity off: Δp on one pair gives τ = Δp·A·r and a static bend τ/k_eff within 5 %.

    The published discretisation (n disks → n−1 hinges, each with k·n in series) has the
    lumped stiffness k_eff = k·n/(n−1), so the analytic bend is τ·(n−1)/(k·n): 0.9 τ/k at 10 disks.
    """
    jp = NO_GRAVITY.joints[joint]
    n = NO_GRAVITY.n_disks
    tau = dp * jp.chamber_area_m2 * jp.moment_arm_m
    expected = tau * (n - 1) / (jp.stiffness_nm_rad * n)
    plus = 4 * joint + 2 * axis
    res = rollout("tip_speed", constant_schedule({plus: dp}), preset="fast", params=NO_GRAVITY)
    bend = res.trajectory.bend_rad[-1]
    assert bend[joint, axis] == pytest.approx(expected, rel=0.05)
    assert abs(bend[joint, 1 - axis]) < 0.01 * expected  # the other axis stays straight
    assert res.bend_limit_hits == []
    # the opposite chamber of the pair bends it the other way by the same amount
    mirrored = rollout(
        "tip_speed", constant_schedule({plus + 1: dp}), preset="fast", params=NO_GRAVITY
    )
    assert mirrored.trajectory.bend_rad[-1][joint, axis] == pytest.approx(
        -bend[joint, axis], rel=1e-3
    )


def test_zero_pressure_holds_still_without_gravity() -> None:
    res = rollout("tip_speed", np.zeros((10, 12)), preset="fast", params=NO_GRAVITY)
    traj = res.trajectory
    assert np.abs(traj.tip_pos_m - traj.tip_pos_m[0]).max() < 1e-9
    assert res.max_tip_speed < 1e-9
    assert np.abs(traj.pressure_pa).max() == 0.0


def test_zero_pressure_under_gravity_settles() -> None:
    traj = rollout("hammer", np.zeros((10, 12)), preset="fast").trajectory
    assert traj.tip_speed_m_s[-1] < 0.05  # sagged under the 2 kg ball, then came to rest
    assert traj.tip_pos_m[-1, 2] < traj.tip_pos_m[0, 2]


def test_pressure_state_follows_command_with_time_constant() -> None:
    res = rollout("tip_speed", constant_schedule({0: 100e3, 4: 100e3, 8: 100e3}), preset="fast")
    traj = res.trajectory
    for joint, tau in enumerate((0.2, 0.5, 0.8)):
        i = int(np.argmin(np.abs(traj.time_s - tau)))
        # first-order lag: 1 − e^{−1} of the step after one time constant
        assert traj.pressure_pa[i, 4 * joint] == pytest.approx(100e3 * (1 - math.exp(-1)), rel=0.03)


@pytest.mark.parametrize("task", ["throw", "hammer", "tip_speed"])
@pytest.mark.parametrize("schedule", ["bang_bang", "all_max", "one_side"])
def test_extreme_schedules_stay_finite(task: str, schedule: str) -> None:
    sched = {
        "bang_bang": bang_bang(),
        "all_max": np.full((10, 12), P_MAX),
        "one_side": constant_schedule(
            {0: P_MAX, 2: P_MAX, 4: P_MAX, 6: P_MAX, 8: P_MAX, 10: P_MAX}
        ),
    }[schedule]
    res = rollout(task, sched, preset="fast", release_step=5 if task == "throw" else None)
    traj = res.trajectory
    for name in ("tip_pos_m", "tip_vel_m_s", "object_pos_m", "plate_force_n", "bend_rad"):
        assert np.isfinite(getattr(traj, name)).all(), name
    assert math.isfinite(res.objective) and res.max_tip_speed < 50.0


def test_extreme_schedule_at_reference_stays_finite_and_reaches_bend_limits() -> None:
    res = rollout("hammer", bang_bang(), preset="reference")
    assert np.isfinite(res.trajectory.tip_pos_m).all() and math.isfinite(res.objective)
    assert res.bend_limit_hits  # swinging between extremes drives some joint to its stop


def test_hammer_pressed_onto_plate_registers_a_hit() -> None:
    """j0.y− at full pressure swings the ball down onto the plate; at rest nothing touches it."""
    down = rollout("hammer", constant_schedule({3: P_MAX}), preset="fast")
    assert down.peak_plate_force_n >= 5.0
    assert down.objective_terms["force_sum_n"] >= 5.0
    ball = down.trajectory.object_pos_m[-1]
    assert np.hypot(ball[0] + 0.5, ball[1] - 0.5) < 0.25  # over the plate
    idle = rollout("hammer", np.zeros((10, 12)), preset="fast")
    assert idle.peak_plate_force_n == 0.0


def test_later_release_lands_the_cube_elsewhere() -> None:
    schedule = bang_bang()
    early = rollout("throw", schedule, release_step=2, preset="fast")
    late = rollout("throw", schedule, release_step=5, preset="fast")
    landing_early = early.trajectory.object_pos_m[-1]
    landing_late = late.trajectory.object_pos_m[-1]
    assert np.linalg.norm(landing_early - landing_late) > 0.1
    assert landing_early[2] < 0.1 and landing_late[2] < 0.1  # both came down on the floor
    # until the early release both episodes are identical
    t_release = 2 * 0.5
    before = early.trajectory.time_s <= t_release
    np.testing.assert_array_equal(
        early.trajectory.object_pos_m[before], late.trajectory.object_pos_m[before]
    )


def test_unstable_parameters_raise_simulation_diverged() -> None:
    stiff = tuple(
        replace(jp, stiffness_nm_rad=1e6, damping_nms_rad=0.0) for jp in ArmParams().joints
    )
    with pytest.raises(SimulationDiverged, match=r"diverged .* at t = "):
        rollout(
            "tip_speed",
            constant_schedule({0: P_MAX}),
            preset="fast",
            params=replace(ArmParams(), joints=stiff),
        )
