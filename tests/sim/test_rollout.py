"""The rollout API: determinism, recording, objectives, files, bad input, batches."""

from __future__ import annotations

import json
import pickle
from dataclasses import replace

import numpy as np
import pytest

from app.policy import SIM_MAX_PRESSURE_PA, Policy
from app.sim import (
    ArmParams,
    RolloutResult,
    SimulationDiverged,
    Trajectory,
    rollout,
    rollout_batch,
)

P_MAX = SIM_MAX_PRESSURE_PA  # 40 psi


def random_schedule(seed: int, task: str = "hammer") -> tuple[np.ndarray, int | None]:
    """A schedule as the optimisers produce it: a random θ decoded by the P=7 policy."""
    policy = Policy(levels=7, with_release=task == "throw")
    decoded = policy.decode(np.random.default_rng(seed).uniform(size=policy.dim))
    return decoded.pressure_schedule_pa, decoded.release_step


def assert_same_result(a: RolloutResult, b: RolloutResult) -> None:
    assert a.objective == b.objective
    assert a.bend_limit_hits == b.bend_limit_hits
    for name in (
        "time_s",
        "tip_pos_m",
        "tip_vel_m_s",
        "object_pos_m",
        "plate_force_n",
        "pressure_pa",
        "bend_rad",
    ):
        np.testing.assert_array_equal(getattr(a.trajectory, name), getattr(b.trajectory, name))


@pytest.mark.parametrize("task", ["throw", "hammer"])
def test_repeat_is_bit_identical(task: str) -> None:
    schedule, release = random_schedule(3, task)
    first = rollout(task, schedule, release_step=release, preset="fast", record_qpos=True)
    again = rollout(task, schedule, release_step=release, preset="fast", record_qpos=True)
    assert_same_result(first, again)
    np.testing.assert_array_equal(first.trajectory.qpos, again.trajectory.qpos)


def test_trajectory_shapes_and_units() -> None:
    schedule, release = random_schedule(1, "throw")
    res = rollout("throw", schedule, release_step=release, preset="fast", record_qpos=True)
    traj = res.trajectory
    assert len(traj) == 501
    np.testing.assert_allclose(traj.time_s, np.arange(501) * 0.01, atol=1e-12)
    assert traj.tip_pos_m.shape == (501, 3) and traj.tip_vel_m_s.shape == (501, 3)
    assert traj.object_pos_m.shape == (501, 3) and traj.plate_force_n.shape == (501,)
    assert traj.pressure_pa.shape == (501, 12) and traj.bend_rad.shape == (501, 3, 2)
    assert traj.qpos is not None and traj.qpos.shape == (501, 61)  # 54 hinges + cube free joint
    np.testing.assert_allclose(traj.tip_speed_m_s, np.linalg.norm(traj.tip_vel_m_s, axis=1))
    # the tip velocity is the time derivative of the tip position
    finite_diff = np.gradient(traj.tip_pos_m, traj.time_s, axis=0)
    assert np.corrcoef(finite_diff[:, 0], traj.tip_vel_m_s[:, 0])[0, 1] > 0.99
    # pressure states stay inside the command range; they start from zero
    assert traj.pressure_pa.min() >= 0 and traj.pressure_pa.max() <= P_MAX
    np.testing.assert_array_equal(traj.pressure_pa[0], np.zeros(12))
    assert res.max_tip_speed == pytest.approx(float(res.tip_speed_100hz.max()))
    assert rollout("tip_speed", schedule, preset="fast").trajectory.qpos is None


def test_objective_does_not_depend_on_record_rate() -> None:
    schedule, _ = random_schedule(5)
    results = [rollout("hammer", schedule, preset="fast", record_hz=hz) for hz in (20, 100, 200)]
    assert [len(r.trajectory) for r in results] == [101, 501, 1001]
    for r in results[1:]:
        assert r.objective == results[0].objective
        np.testing.assert_array_equal(r.tip_speed_100hz, results[0].tip_speed_100hz)
    np.testing.assert_array_equal(
        results[2].trajectory.tip_pos_m[::2], results[1].trajectory.tip_pos_m
    )


def test_objectives_follow_their_definitions() -> None:
    schedule, release = random_schedule(7, "throw")
    throw = rollout("throw", schedule, release_step=release, preset="fast", record_hz=2.0)
    traj = throw.trajectory  # 2 Hz: samples exactly at the control-step ends
    speed_sum = traj.tip_speed_m_s[1 : release + 1].sum()
    assert throw.objective == pytest.approx(speed_sum + np.linalg.norm(traj.object_pos_m[-1]))

    hammer = rollout("hammer", schedule, preset="fast", record_hz=2.0)
    traj = hammer.trajectory
    dist = np.linalg.norm(traj.object_pos_m[1:] - np.array([-0.5, 0.5, 0.0]), axis=1)
    dist_term = dist[6:].sum()  # steps t = 7..10 (t ≥ 0.7 H)
    assert hammer.objective_terms["distance_sum_m"] == pytest.approx(dist_term)
    assert hammer.objective_terms["force_sum_n"] == pytest.approx(traj.plate_force_n[1:].sum())
    expected = (
        hammer.objective_terms["momentum_sum"] + traj.plate_force_n[1:].sum() - dist_term
    ) / 1000
    assert hammer.objective == pytest.approx(expected)

    tip = rollout("tip_speed", schedule, preset="fast")
    assert tip.objective == tip.max_tip_speed == pytest.approx(tip.trajectory.tip_speed_m_s.max())


def test_npz_round_trip(tmp_path) -> None:
    schedule, _ = random_schedule(2)
    traj = rollout("hammer", schedule, preset="fast", record_qpos=True).trajectory
    path = tmp_path / "traj.npz"
    traj.to_npz(path)
    back = Trajectory.from_npz(path)
    for name in (
        "time_s",
        "tip_pos_m",
        "tip_vel_m_s",
        "tip_speed_m_s",
        "object_pos_m",
        "plate_force_n",
        "pressure_pa",
        "bend_rad",
        "qpos",
    ):
        np.testing.assert_array_equal(getattr(back, name), getattr(traj, name))
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not a trajectory file"):
        Trajectory.from_npz(tmp_path / "other.npz")


def test_summary_is_json() -> None:
    schedule, release = random_schedule(4, "throw")
    summary = rollout("throw", schedule, release_step=release, preset="fast").to_summary()
    back = json.loads(json.dumps(summary))
    assert back["task"] == "throw" and back["preset"] == "fast"
    assert back["release_step"] == release
    assert len(back["tip_speed_100hz"]) == 501
    assert back["max_tip_speed"] == pytest.approx(max(back["tip_speed_100hz"]), abs=1e-6)
    for key in ("objective", "wall_s", "bend_limit_hits", "final_object_pos_m"):
        assert key in back


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"task": "juggle"}, "unknown task 'juggle'"),
        ({"preset": "ultra"}, "unknown preset 'ultra'"),
        ({"schedule": np.zeros((10, 11))}, r"shape \(H, 12\)"),
        ({"schedule": np.full((10, 12), -5.0)}, "step 1, chamber j0.x\\+: -5.0 Pa is outside"),
        ({"schedule": np.full((10, 12), 3e5)}, "outside the allowed"),
        ({"schedule": np.full((10, 12), np.nan)}, "not a finite number"),
        ({"task": "throw"}, "throw needs release_step"),
        ({"task": "throw", "release_step": 11}, r"release_step must be in 1\.\.10"),
        ({"release_step": 3}, r"no release step \(release_step applies to throw only\)"),
        ({"record_hz": 0.0}, "record_hz must be a positive number"),
        ({"schedule": np.zeros((7, 12))}, "not a whole number"),
    ],
)
def test_bad_input_raises_value_error(kwargs: dict, message: str) -> None:
    args = {"task": "hammer", "schedule": np.zeros((10, 12)), "preset": "fast"} | kwargs
    task, schedule = args.pop("task"), args.pop("schedule")
    with pytest.raises(ValueError, match=message):
        rollout(task, schedule, **args)


def test_batch_matches_single_rollouts_in_order() -> None:
    items = [random_schedule(seed, "throw") for seed in range(4)]
    schedules = np.stack([s for s, _ in items])
    releases = [r for _, r in items]
    pooled = rollout_batch("throw", schedules, release_steps=releases, preset="fast", n_workers=2)
    serial = rollout_batch("throw", schedules, release_steps=releases, preset="fast", n_workers=1)
    assert len(pooled) == len(serial) == 4
    for a, b in zip(pooled, serial, strict=True):
        assert_same_result(a, b)
    assert [r.release_step for r in pooled] == releases


def test_batch_refuses_bad_input_before_running() -> None:
    schedules = np.zeros((3, 10, 12))
    schedules[2, 4, 7] = -1.0
    with pytest.raises(ValueError, match=r"episode 2: step 5, chamber j1\.y-: -1\.0 Pa"):
        rollout_batch("hammer", schedules, preset="fast", n_workers=2)
    with pytest.raises(ValueError, match="3 schedules but 2 release steps"):
        rollout_batch("throw", np.zeros((3, 10, 12)), release_steps=[1, 2], preset="fast")
    assert rollout_batch("tip_speed", [], preset="fast") == []


def test_diverged_episode_in_a_pool_names_its_index() -> None:
    """A blow-up inside a worker process comes back as SimulationDiverged, index included."""
    stiff = tuple(
        replace(jp, stiffness_nm_rad=1e6, damping_nms_rad=0.0) for jp in ArmParams().joints
    )
    # without gravity, episode 0 (no pressure) stays exactly at rest; episode 1 blows up
    params = replace(ArmParams(), joints=stiff, gravity_m_s2=(0.0, 0.0, 0.0))
    schedules = np.zeros((2, 10, 12))
    schedules[1, :, 0] = P_MAX
    with pytest.raises(SimulationDiverged, match=r"episode 1: simulation diverged") as info:
        rollout_batch("tip_speed", schedules, preset="fast", params=params, n_workers=2)
    assert info.value.task == "tip_speed" and info.value.time_s > 0
    again = pickle.loads(pickle.dumps(info.value))
    assert (str(again), again.preset) == (str(info.value), "fast")
