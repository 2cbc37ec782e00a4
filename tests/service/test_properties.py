"""Property tests: repeats → mean and SEM (planned vs executed θ: tests/test_policy.py)."""

from __future__ import annotations

import math
import statistics

from hypothesis import given
from hypothesis import strategies as st

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
