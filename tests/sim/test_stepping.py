"""Episode: the rollout one control step at a time is the rollout itself."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim import Episode, rollout
from app.sim.model import EEF_LINVEL_SENSOR

from .test_rollout import assert_same_result, random_schedule


@pytest.mark.parametrize(
    ("task", "hold", "rule"),
    [("throw", "linear", "published"), ("throw", "zero", "paper"), ("hammer", "zero", "paper")],
)
def test_stepping_row_by_row_is_bit_identical_to_rollout(task: str, hold: str, rule: str) -> None:
    schedule, release = random_schedule(5, task)
    if task == "throw":
        release = 3  # released mid-episode, so the gripper opens (the weld lets go) while stepping
    whole = rollout(
        task,
        schedule,
        release_step=release,
        preset="fast",
        command_hold=hold,
        objective_rule=rule,
        record_qpos=True,
    )
    ep = Episode(
        task, horizon=10, preset="fast", command_hold=hold, objective_rule=rule, record_qpos=True
    )
    tip_vel = []
    for t, row in enumerate(schedule, start=1):
        ep.step(row, open_gripper=release is not None and t > release)
        tip_vel.append(ep.reading(EEF_LINVEL_SENSOR))
    stepped = ep.result()
    assert_same_result(stepped, whole)
    assert stepped.objective_by_rule == whole.objective_by_rule
    assert stepped.release_step == whole.release_step
    np.testing.assert_array_equal(stepped.trajectory.qpos, whole.trajectory.qpos)
    # the readings after each step are the trajectory's samples at the control steps' ends
    ends = np.searchsorted(whole.trajectory.time_s, np.arange(1, 11) * 0.5 - 1e-9)
    np.testing.assert_array_equal(np.array(tip_vel), whole.trajectory.tip_vel_m_s[ends])


def test_episode_refuses_misuse() -> None:
    ep = Episode("hammer", horizon=2, preset="fast")
    with pytest.raises(ValueError, match="0 are done"):
        ep.result()
    with pytest.raises(ValueError, match="gripper only exists in throw"):
        ep.step(np.zeros(12), open_gripper=True)
    with pytest.raises(ValueError, match="holds the cube in step 1"):
        Episode("throw", preset="fast").step(np.zeros(12), open_gripper=True)
    with pytest.raises(ValueError, match=r"control step 1: .*outside"):
        ep.step(np.full(12, 1e6))
    ep.step(np.zeros(12))
    ep.step(np.zeros(12))
    with pytest.raises(ValueError, match="all are done"):
        ep.step(np.zeros(12))
    with pytest.raises(ValueError, match="horizon"):
        Episode("hammer", horizon=0)
