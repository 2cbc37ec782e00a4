"""The few-parameter policy: g, pairing, levels, hardware limits, encode/decode, hashes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.policy import (
    CHAMBER_NAMES,
    SIM_MAX_PRESSURE_PA,
    Policy,
    PolicyError,
    PressureLimitError,
    PressureLimits,
    check_schedule,
    schedule_hash,
)


@pytest.mark.parametrize(("levels", "n_actions"), [(2, 64), (5, 15_625), (7, 117_649), (10, 10**6)])
def test_action_set_size(levels: int, n_actions: int) -> None:
    policy = Policy(levels=levels)
    assert policy.n_actions == n_actions
    assert policy.dim == 10 and Policy(levels=levels, with_release=True).dim == 11


@pytest.mark.parametrize("levels", [2, 10])
def test_g_edges_theta_zero_and_one(levels: int) -> None:
    policy = Policy(levels=levels)
    m = policy.n_actions
    actions, release = policy.actions_from_theta(np.zeros(10))
    assert actions.tolist() == [0] * 10 and release is None
    actions, _ = policy.actions_from_theta(np.ones(10))
    assert actions.tolist() == [m - 1] * 10  # θ = 1 scales to M, clipped to M − 1
    # just below a bin edge and on it
    edge = np.full(10, 1.0 / m)
    assert policy.actions_from_theta(edge)[0].tolist() == [1] * 10
    assert policy.actions_from_theta(np.nextafter(edge, 0))[0].tolist() == [0] * 10


def test_g_action_zero_is_all_minus_and_last_is_all_plus_in_sim_mode() -> None:
    policy = Policy(levels=2)
    low = policy.decode(np.zeros(10)).pressure_schedule_pa
    high = policy.decode(np.ones(10)).pressure_schedule_pa
    np.testing.assert_allclose(low[:, 0::2], 0.0)  # "+" chambers at p_min
    np.testing.assert_allclose(low[:, 1::2], SIM_MAX_PRESSURE_PA)  # partners mirrored
    np.testing.assert_allclose(high[:, 0::2], SIM_MAX_PRESSURE_PA)
    np.testing.assert_allclose(high[:, 1::2], 0.0)


def test_release_step_edges() -> None:
    policy = Policy(levels=2, with_release=True)
    assert policy.decode(np.zeros(11)).release_step == 1
    assert policy.decode(np.ones(11)).release_step == 10
    assert policy.decode(np.r_[np.zeros(10), 0.55]).release_step == 6


@given(st.lists(st.floats(0.0, 1.0), min_size=10, max_size=10), st.sampled_from([2, 5, 7, 10]))
@settings(max_examples=60, deadline=None)
def test_pairing_sim_mode(theta: list[float], levels: int) -> None:
    schedule = Policy(levels=levels).decode(np.asarray(theta)).pressure_schedule_pa
    np.testing.assert_allclose(schedule[:, 0::2] + schedule[:, 1::2], SIM_MAX_PRESSURE_PA)
    assert schedule.min() >= 0.0 and schedule.max() <= SIM_MAX_PRESSURE_PA
    # every pressure is one of the P levels
    grid = np.linspace(0.0, SIM_MAX_PRESSURE_PA, levels)
    assert np.abs(schedule[..., None] - grid).min(axis=-1).max() < 1e-6


def test_digit_order_first_paired_command_is_most_significant() -> None:
    policy = Policy(levels=2)
    levels = policy.levels_from_actions(np.array([1, 32]))
    assert levels.tolist() == [[0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 0, 0]]
    schedule = policy.schedule_from_levels(levels)
    assert schedule[1, 0] == SIM_MAX_PRESSURE_PA and schedule[0, 10] == SIM_MAX_PRESSURE_PA


def test_hardware_mode_offsets_around_nominal() -> None:
    nominal = np.linspace(80e3, 140e3, 12)
    limits = PressureLimits(nominal_pa=tuple(nominal), max_step_pa=30e3, source_pa=205e3)
    policy = Policy(levels=3, limits=limits)
    table = policy.level_pressures_pa()
    np.testing.assert_allclose(table[0], nominal[0] + np.array([-30e3, 0.0, 30e3]))
    np.testing.assert_allclose(table[1], nominal[1] - np.array([-30e3, 0.0, 30e3]))  # +δ / −δ
    schedule = policy.decode(np.full(10, 0.999)).pressure_schedule_pa
    deviation = schedule - nominal
    np.testing.assert_allclose(deviation[:, 0::2], 30e3)
    np.testing.assert_allclose(deviation[:, 1::2], -30e3)
    assert schedule.max() <= 205e3 and schedule.min() >= 0


def test_hardware_limits_refuse_bad_nominals() -> None:
    with pytest.raises(PolicyError, match=r"chamber j0\.x\+: nominal 190000 Pa"):
        PressureLimits(nominal_pa=(190e3,) + (100e3,) * 11, max_step_pa=30e3, source_pa=205e3)
    with pytest.raises(PolicyError, match=r"chamber j2\.y-"):
        PressureLimits(nominal_pa=(100e3,) * 11 + (10e3,))
    with pytest.raises(PolicyError, match="max_step_pa must be > 0"):
        PressureLimits(max_step_pa=0.0)


def test_hardware_check_names_chamber_step_and_value() -> None:
    policy = Policy(levels=2, limits=PressureLimits())
    schedule = np.full((10, 12), 100e3)
    schedule[6, 9] = 131_000.0  # step 7, chamber j2.x−: 1 kPa past nominal + 30 kPa
    with pytest.raises(PressureLimitError) as info:
        policy.check(schedule)
    err = info.value
    assert (err.chamber, err.step, err.value_pa) == (9, 7, 131_000.0)
    assert "step 7" in str(err) and CHAMBER_NAMES[9] in str(err) and "131000.0 Pa" in str(err)
    with pytest.raises(PressureLimitError, match=r"step 1, chamber j0\.x\+: 300000\.0 Pa"):
        check_schedule(np.full((10, 12), 3e5))
    with pytest.raises(PolicyError, match=r"shape \(H, 12\)"):
        check_schedule(np.zeros((10, 4)))


def test_theta_outside_unit_box_is_refused_with_its_index() -> None:
    policy = Policy(levels=7)
    with pytest.raises(PolicyError, match=r"θ\[3\] = 1\.5 is outside \[0, 1\]"):
        policy.decode(np.array([0, 0, 0, 1.5, 0, 0, 0, 0, 0, 0]))
    with pytest.raises(PolicyError, match="θ must have 11 entries"):
        Policy(levels=7, with_release=True).decode(np.zeros(10))
    with pytest.raises(PolicyError, match="finite"):
        policy.decode(np.full(10, np.nan))
    with pytest.raises(PolicyError, match="levels"):
        Policy(levels=1)


@given(
    st.lists(st.integers(0, 7**6 - 1), min_size=10, max_size=10),
    st.integers(1, 10),
)
@settings(max_examples=60, deadline=None)
def test_encode_decode_round_trip(actions: list[int], release: int) -> None:
    policy = Policy(levels=7, with_release=True)
    theta = policy.theta_from_actions(np.asarray(actions), release)
    decoded = policy.decode(theta)
    assert decoded.action_indices.tolist() == actions and decoded.release_step == release
    theta_again = policy.encode(decoded.pressure_schedule_pa, decoded.release_step)
    np.testing.assert_array_equal(theta_again, theta)
    np.testing.assert_array_equal(
        policy.decode(theta_again).pressure_schedule_pa, decoded.pressure_schedule_pa
    )


def test_encode_refuses_off_grid_schedules() -> None:
    policy = Policy(levels=2)
    schedule = policy.decode(np.zeros(10)).pressure_schedule_pa.copy()
    schedule[2, 0] = 1000.0
    with pytest.raises(PolicyError, match=r"step 3, pair j0\.x"):
        policy.encode(schedule)


def test_hardware_round_trip() -> None:
    policy = Policy(levels=5, limits=PressureLimits(nominal_pa=120e3))
    theta = np.random.default_rng(0).uniform(size=10)
    decoded = policy.decode(theta)
    again = policy.decode(policy.encode(decoded.pressure_schedule_pa))
    np.testing.assert_array_equal(again.action_indices, decoded.action_indices)


def test_schedule_hash_binds_exact_schedule_and_release() -> None:
    schedule = Policy(levels=7).decode(np.linspace(0, 1, 10)).pressure_schedule_pa
    h = schedule_hash(schedule, 4)
    assert len(h) == 64 and int(h, 16) >= 0
    assert schedule_hash(schedule.tolist(), 4) == h  # a JSON round trip keeps it
    assert schedule_hash(schedule + 1e-5, 4) == h  # below 1 mPa: same schedule
    changed = schedule.copy()
    changed[9, 11] += 0.01  # 10 mPa
    assert schedule_hash(changed, 4) != h
    assert schedule_hash(schedule, 5) != h
    assert schedule_hash(schedule, None) != h


def test_pressure_limit_error_survives_pickling() -> None:
    import pickle

    from app.policy import PressureLimitError

    err = PressureLimitError("step 2, chamber j0.x+: too high", chamber=0, step=2, value_pa=3e5)
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, PressureLimitError)
    assert (str(back), back.chamber, back.step, back.value_pa) == (str(err), 0, 2, 3e5)


def test_schedule_hash_of_a_non_finite_schedule_is_defined_and_distinct() -> None:
    import warnings

    from app.policy import schedule_hash

    schedule = np.full((10, 12), 1e5)
    nan, inf = schedule.copy(), schedule.copy()
    nan[3, 4], inf[3, 4] = np.nan, np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no invalid-cast RuntimeWarning
        hashes = {schedule_hash(s, None) for s in (schedule, nan, inf)}
    assert len(hashes) == 3
    assert schedule_hash(nan.copy(), None) == schedule_hash(nan, None)


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
thetas = st.data()


def _theta(policy: Policy, data: st.DataObject) -> np.ndarray:
    return np.array(data.draw(st.lists(st.floats(0, 1), min_size=policy.dim, max_size=policy.dim)))


@settings(max_examples=60, deadline=None)
@given(policies, thetas)
def test_grid_coordinates_are_the_decoded_levels_and_release_step(policy, data):
    theta = np.stack([_theta(policy, data) for _ in range(3)])
    grid = policy.grid_from_theta(theta)
    assert grid.shape == (3, len(policy.grid_sizes()))
    assert (grid < np.asarray(policy.grid_sizes())).all() and (grid >= 0).all()
    back = policy.theta_from_grid(grid)
    for th, row, b in zip(theta, grid, back, strict=True):
        d = policy.decode(th)
        release = [d.release_step - 1] if policy.with_release else []
        assert row.tolist() == [*d.level_indices.ravel().tolist(), *release]
        # the bin centre of the same schedule
        np.testing.assert_array_equal(
            b, policy.theta_from_actions(d.action_indices, d.release_step)
        )


@settings(max_examples=60, deadline=None)
@given(policies, thetas)
def test_a_run_of_the_plan_gives_the_planned_theta_back(policy, data):
    theta = _theta(policy, data)
    planned = policy.decode(theta)
    executed = policy.executed_theta(theta, planned.pressure_schedule_pa, planned.release_step)
    np.testing.assert_array_equal(executed, theta)


@settings(max_examples=60, deadline=None)
@given(policies, thetas)
def test_an_executed_schedule_snaps_to_the_nearest_levels(policy, data):
    """Errors under half a level's spacing: the plan ran (θ comes back); a different level in
    step 1: the centre of the bins of what ran."""
    theta = _theta(policy, data)
    planned = policy.decode(theta)
    spacing = float(np.abs(np.diff(policy.level_pressures_pa()[0])).min())
    seed = data.draw(st.integers(0, 2**31 - 1))
    noise = np.random.default_rng(seed).uniform(-0.45, 0.45, planned.pressure_schedule_pa.shape)
    noisy = planned.pressure_schedule_pa + noise * spacing
    snapped = policy.encode(noisy, planned.release_step, snap=True)
    np.testing.assert_array_equal(policy.decode(snapped).action_indices, planned.action_indices)
    np.testing.assert_array_equal(policy.executed_theta(theta, noisy, planned.release_step), theta)
    levels = planned.level_indices.copy()
    levels[0, 0] = (levels[0, 0] + 1) % policy.levels
    other = policy.schedule_from_levels(levels)
    executed = policy.executed_theta(theta, other, planned.release_step)
    np.testing.assert_array_equal(policy.decode(executed).level_indices, levels)
    np.testing.assert_array_equal(
        executed,
        policy.theta_from_actions(policy.decode(executed).action_indices, planned.release_step),
    )


def test_a_different_release_step_is_a_different_execution() -> None:
    policy = Policy(levels=3, with_release=True)
    theta = np.full(11, 0.42)
    planned = policy.decode(theta)
    other = policy.executed_theta(
        theta, planned.pressure_schedule_pa, planned.release_step % 10 + 1
    )
    assert policy.decode(other).release_step == planned.release_step % 10 + 1
    assert other[10] != theta[10]


def test_snapping_encode_takes_schedules_beyond_the_bounds_but_not_malformed_ones() -> None:
    policy = Policy(levels=2, limits=PressureLimits(nominal_pa=100_000.0))
    beyond = np.tile([150_000.0, 50_000.0], (10, 6))  # beyond nominal ± max step (30 kPa)
    with pytest.raises(PressureLimitError):
        policy.encode(beyond)
    theta = policy.encode(beyond, snap=True)
    assert policy.decode(theta).pressure_schedule_pa[0, :2].tolist() == [130_000.0, 70_000.0]
    with pytest.raises(PolicyError, match=r"10×12 finite numbers \(Pa\), got shape \(9, 12\)"):
        policy.encode(beyond[:9], snap=True)
    with pytest.raises(PolicyError, match="finite"):
        policy.encode(np.full((10, 12), np.nan), snap=True)
