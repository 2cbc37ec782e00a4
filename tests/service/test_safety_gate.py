"""The safety gate as a property: whatever schedule and confirmation a forged database row
carries, a claim hands a hardware trial to a worker only when the schedule is within the
experiment's limits and confirmed under its exact hash."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.db.models import Trial
from app.policy import Policy, PressureLimits, schedule_hash
from app.service import leases
from app.service import lifecycle as lc
from app.service.auth import Actor
from app.service.errors import ConfirmationMismatch
from app.service.schemas import ClaimIn

WORKER = Actor("worker", "worker")
LIMITS = PressureLimits(nominal_pa=100_000.0, max_step_pa=30_000.0, source_pa=205_000.0)
POLICY = Policy(levels=3, limits=LIMITS)

schedules = st.one_of(
    st.just("planned"),
    st.tuples(
        st.just("perturb"),
        st.integers(0, 9),
        st.integers(0, 11),
        st.floats(-120_000, 120_000, allow_nan=False),
    ),
    st.tuples(st.just("random"), st.integers(0, 2**31 - 1)),
    st.tuples(st.just("nan"), st.integers(0, 9), st.integers(0, 11)),
)
confirmations = st.sampled_from(["none", "current", "original", "random"])


def _forge(planned: np.ndarray, how) -> list[list[float]]:
    s = planned.copy()
    if how == "planned":
        return s.tolist()
    if how[0] == "perturb":
        s[how[1], how[2]] += how[3]
    elif how[0] == "random":
        s = np.random.default_rng(how[1]).uniform(-50_000, 300_000, s.shape)
    else:
        s[how[1], how[2]] = np.nan
    return s.tolist()


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    st.lists(
        st.tuples(st.lists(st.floats(0, 1), min_size=10, max_size=10), schedules, confirmations),
        min_size=1,
        max_size=4,
    )
)
def test_only_confirmed_in_limit_schedules_reach_a_worker(db, make_experiment, make_trial, rows):
    exp_id = make_experiment(target="hardware")
    ids = []
    for theta, how, conf in rows:
        tid = make_trial(exp_id, theta=theta)
        planned = POLICY.decode(np.asarray(theta)).pressure_schedule_pa
        forged = _forge(planned, how)
        with db.write() as s:
            t = s.get(Trial, tid)
            t.pressure_schedule_pa = forged
            t.status = lc.QUEUED
            t.confirmed_hash = {
                "none": None,
                "current": schedule_hash(forged, None),
                "original": schedule_hash(planned, None),
                "random": "ab" * 32,
            }[conf]
        ids.append(tid)
    with db.write() as s:
        claims = leases.claim(
            s,
            ClaimIn(worker_id="w", target="hardware", max_trials=64),
            actor=WORKER,
            lease_seconds=60,
            max_attempts=3,
        )
    claimed = {c.trial.id for c in claims}
    with db.read() as s:
        for tid in ids:
            t = s.get(Trial, tid)
            sched = np.asarray(t.pressure_schedule_pa, dtype=np.float64)
            ok = (
                bool(np.all(np.isfinite(sched)))
                and bool(np.all(sched >= LIMITS.lower_pa - 1e-6))
                and bool(np.all(sched <= LIMITS.upper_pa + 1e-6))
                and t.confirmed_hash == schedule_hash(sched, None)
            )
            if tid in claimed:
                assert ok, (tid, t.confirmed_hash)
                assert t.status == lc.RUNNING
            else:
                assert not ok
                assert t.status == lc.NEEDS_REVIEW
                assert "safety gate" in t.status_reason


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.text(alphabet="0123456789abcdef", min_size=64, max_size=64))
def test_confirming_any_other_hash_is_refused(db, make_experiment, make_trial, forged_hash):
    from app.service.trials import confirm

    exp_id = make_experiment(target="hardware")
    tid = make_trial(exp_id)
    with db.read() as s:
        t = s.get(Trial, tid)
        current = schedule_hash(t.pressure_schedule_pa, t.release_step)
    if forged_hash == current:
        return
    try:
        with db.write() as s:
            confirm(s, tid, forged_hash, actor=Actor("olivia", "operator"))
    except ConfirmationMismatch as exc:
        assert "current schedule" in str(exc)
    else:
        raise AssertionError("a wrong hash was accepted")
    with db.read() as s:
        assert s.get(Trial, tid).status == lc.AWAITING_CONFIRMATION
