"""Property tests: repeats → mean and SEM; planned vs executed θ."""

from __future__ import annotations

import math
import statistics

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from app.policy import Policy, PressureLimits
from app.service.leases import theta_from_schedule
from app.service.measurements import objective_from_repeats

values = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False, allow_infinity=False)


@given(st.lists(values, min_size=1, max_size=30))
def test_mean_and_sem_of_repeats(repeats):
    mean, sem = objective_from_repeats(repeats)
    assert math.isclose(mean, statistics.fmean(repeats), rel_tol=1e-9, abs_tol=1e-9)
    if len(repeats) == 1:
        assert sem is None
    else:
        expected = statistics.stdev(repeats) / math.sqrt(len(repeats))
        assert sem is not None and sem >= 0
        assert math.isclose(sem, expected, rel_tol=1e-6, abs_tol=1e-9)


@given(st.floats(-100, 100), st.integers(2, 20))
def test_identical_repeats_have_zero_sem(value, n):
    mean, sem = objective_from_repeats([value] * n)
    assert math.isclose(mean, value, abs_tol=1e-12)
    assert sem is not None and sem <= 1e-9 * max(1.0, abs(value))


policies = st.sampled_from(
    [
        Policy(levels=2),
        Policy(levels=5, with_release=True),
        Policy(levels=7, horizon=4),
        Policy(levels=3, limits=PressureLimits(nominal_pa=100_000.0)),
        Policy(
            levels=4,
            horizon=6,
            with_release=True,
            limits=PressureLimits(nominal_pa=120_000.0, max_step_pa=20_000.0),
        ),
    ]
)


@settings(max_examples=60, deadline=None)
@given(policies, st.data())
def test_executed_as_planned_gives_the_planned_actions(policy, data):
    theta = np.array(data.draw(st.lists(st.floats(0, 1), min_size=policy.dim, max_size=policy.dim)))
    planned = policy.decode(theta)
    executed = theta_from_schedule(policy, planned.pressure_schedule_pa, planned.release_step)
    again = policy.decode(executed)
    np.testing.assert_array_equal(again.action_indices, planned.action_indices)
    np.testing.assert_array_equal(again.pressure_schedule_pa, planned.pressure_schedule_pa)
    assert again.release_step == planned.release_step


@settings(max_examples=60, deadline=None)
@given(policies, st.data())
def test_executed_schedule_off_grid_snaps_to_nearest_level(policy, data):
    """A worker that ran a schedule with small pressure errors (under half a level's spacing)
    reports θ of the planned actions; a schedule that ran different levels reports those."""
    theta = np.array(data.draw(st.lists(st.floats(0, 1), min_size=policy.dim, max_size=policy.dim)))
    planned = policy.decode(theta)
    table = policy.level_pressures_pa()
    spacing = float(np.abs(np.diff(table[0])).min())
    seed = data.draw(st.integers(0, 2**31 - 1))
    noise = np.random.default_rng(seed).uniform(-0.45, 0.45, planned.pressure_schedule_pa.shape)
    executed = theta_from_schedule(
        policy, planned.pressure_schedule_pa + noise * spacing, planned.release_step
    )
    np.testing.assert_array_equal(policy.decode(executed).action_indices, planned.action_indices)
    # running a different level in step 1 changes the executed θ (not the planned one)
    levels = planned.level_indices.copy()
    levels[0, 0] = (levels[0, 0] + 1) % policy.levels
    other = policy.schedule_from_levels(levels)
    executed2 = theta_from_schedule(policy, other, planned.release_step)
    np.testing.assert_array_equal(policy.decode(executed2).level_indices, levels)
    assert policy.decode(executed2).action_indices[0] != planned.action_indices[0]
