"""HandfulEnv: Gymnasium's checks, and returns equal to the simulator's objective."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from app.rl.env import HandfulEnv
from app.sim import rollout


def run_episode(env: HandfulEnv, actions: np.ndarray) -> tuple[float, dict]:
    env.reset(seed=0)
    total = 0.0
    for t, a in enumerate(actions, start=1):
        obs, r, terminated, truncated, info = env.step(a)
        assert obs.shape == env.observation_space.shape and np.isfinite(obs).all()
        assert not truncated and terminated == (t == len(actions))
        total += r
    return total, info


@pytest.mark.parametrize("rule", ["paper", "published"])
@pytest.mark.parametrize(
    ("task", "release", "hold"),
    [
        ("throw", 2, "linear"),
        ("throw", 4, "zero"),
        ("throw", None, "linear"),
        ("hammer", None, "linear"),
        ("hammer", None, "zero"),
        ("tip_speed", None, "linear"),
    ],
)
def test_return_equals_the_rollout_objective(
    task: str, release: int | None, hold: str, rule: str
) -> None:
    env = HandfulEnv(task, preset="fast", command_hold=hold, objective_rule=rule)
    rng = np.random.default_rng(11)
    actions = rng.uniform(size=(10, *env.action_space.shape)).astype(np.float32)
    if task == "throw":
        actions[:, -1] = np.maximum(actions[:, -1], 0.01)  # closed (≥ 0.001 of full scale)
        actions[0, -1] = 0.0  # step 1 always holds the cube: an open command there is ignored
        if release is not None:
            actions[release, -1] = 0.0  # t_R = release: open from step t_R + 1
            actions[release + 1 :: 2, -1] = 0.5  # once open, the gripper stays open
    total, info = run_episode(env, actions)
    schedule = actions[:, :12].astype(np.float64) * env.max_pressure_pa
    np.testing.assert_array_equal(info["schedule_pa"], schedule)
    expected_release = (release or 10) if task == "throw" else None
    assert info["release_step"] == expected_release
    res = rollout(
        task,
        schedule,
        release_step=expected_release,
        preset="fast",
        command_hold=hold,
        objective_rule=rule,
    )
    assert info["objective"] == res.objective  # the episode is the rollout, bit for bit
    assert total == pytest.approx(res.objective, rel=1e-9, abs=1e-12)
    assert res.objective > 0


def test_joint_states_extend_the_observation() -> None:
    plain = HandfulEnv("hammer", preset="fast")
    joints = HandfulEnv("hammer", preset="fast", joint_states=True)
    assert plain.observation_space.shape == (6,)
    assert joints.observation_space.shape == (18,)
    assert HandfulEnv("tip_speed", preset="fast").observation_space.shape == (3,)
    assert HandfulEnv("throw", preset="fast").action_space.shape == (13,)
    a = np.full(12, 0.8, dtype=np.float32)
    a[[1, 3, 5, 7, 9, 11]] = 0.0  # one side of each pair: the joints bend
    o1 = plain.reset()[0], plain.step(a)[0]
    o2 = joints.reset()[0], joints.step(a)[0]
    np.testing.assert_array_equal(o1[1], o2[1][:6])
    bends, rates = o2[1][6:12], o2[1][12:]
    assert np.abs(bends).max() > 0.01 and np.abs(rates).max() > 0.01
    assert not np.any(o2[0][6:])  # at rest, straight, at reset


@pytest.mark.parametrize("task", ["throw", "hammer"])
def test_gymnasium_env_checker_passes(task: str) -> None:
    check_env(HandfulEnv(task, preset="fast", joint_states=True), skip_render_check=True)


def test_bad_settings_and_misuse() -> None:
    with pytest.raises(ValueError, match="unknown task"):
        HandfulEnv("juggle")
    with pytest.raises(ValueError, match="unknown command hold"):
        HandfulEnv("hammer", command_hold="cubic")
    env = HandfulEnv("hammer", preset="fast")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(12))
    env.reset()
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(13))
    assert math.isfinite(env.step(np.zeros(12))[1])
