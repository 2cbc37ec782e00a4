"""Lost leases on the service's clock (no sleeping): a sim trial is requeued up to max_attempts
then failed; a hardware trial goes to needs_review and is never rerun on its own; a late result
is refused; heartbeats keep a lease alive. (The API's background sweep: tests/api.)"""

from __future__ import annotations

from datetime import datetime, timedelta

import pytest

from app.db.base import utcnow
from app.db.models import Preview, Trial
from app.policy import schedule_hash
from app.service import leases, trials
from app.service import lifecycle as lc
from app.service.auth import Actor
from app.service.errors import LeaseLost
from app.service.schemas import ClaimIn, ResultIn

WORKER = Actor("worker", "worker")
LEASE_S, ATTEMPTS = 30.0, 2


def claim(
    db, target: str, now: datetime, *, claim_id: str | None = None, worker_id: str = "w", n=1
) -> list:
    with db.write() as s:
        return leases.claim(
            s,
            ClaimIn(worker_id=worker_id, target=target, max_trials=n, claim_id=claim_id),
            actor=WORKER,
            lease_seconds=LEASE_S,
            max_attempts=ATTEMPTS,
            now=now,
        )


def sweep(db, now: datetime) -> int:
    with db.write() as s:
        return leases.sweep_expired(s, max_attempts=ATTEMPTS, now=now)


def trial(db, trial_id: int) -> Trial:
    with db.read() as s:
        t = s.get(Trial, trial_id)
        s.expunge(t)
        return t


def test_a_sim_trial_is_requeued_then_failed(db, make_experiment, make_trial, tmp_path):
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    t0 = utcnow()
    [c1] = claim(db, "sim", t0)
    assert sweep(db, t0 + timedelta(seconds=LEASE_S - 1)) == 0
    assert sweep(db, t0 + timedelta(seconds=LEASE_S + 1)) == 1
    t = trial(db, tid)
    assert t.status == lc.QUEUED
    assert "attempt 1/2" in t.status_reason and "stopped heartbeating" in t.status_reason
    with db.write() as s, pytest.raises(LeaseLost, match="late result"):
        leases.report_result(
            s,
            tid,
            ResultIn(lease_id=c1.lease_id, objective=1.0),
            actor=WORKER,
            artifacts_dir=tmp_path,
            max_attempts=ATTEMPTS,
        )
    t1 = t0 + timedelta(seconds=2 * LEASE_S)
    [c2] = claim(db, "sim", t1)
    assert c2.trial.id == tid and c2.trial.attempts == 2
    assert sweep(db, t1 + timedelta(seconds=LEASE_S + 1)) == 1
    t = trial(db, tid)
    assert t.status == lc.FAILED and "2 attempts" in t.status_reason
    assert t.n_measurements == 0


def test_a_hardware_trial_goes_to_needs_review_and_stays(db, make_experiment, make_trial):
    exp_id = make_experiment(target="hardware")
    tid = make_trial(exp_id, status=lc.AWAITING_CONFIRMATION)
    with db.write() as s:  # the operator previews, then confirms what the trial will run
        t = s.get(Trial, tid)
        digest = schedule_hash(t.pressure_schedule_pa, t.release_step)
        s.add(
            Preview(
                trial_id=tid,
                schedule_hash=digest,
                hold=t.experiment.command_hold,
                sim_preset=t.experiment.sim_preset,
                job_id="p1",
                previewed_by="olivia",
            )
        )
        s.flush()
        trials.confirm(s, tid, digest, actor=Actor("olivia", "operator"))
    t0 = utcnow()
    [c] = claim(db, "hardware", t0)
    assert sweep(db, t0 + timedelta(seconds=LEASE_S + 1)) == 1
    t = trial(db, tid)
    assert t.status == lc.NEEDS_REVIEW and "never rerun on its own" in t.status_reason
    assert claim(db, "hardware", t0 + timedelta(seconds=10 * LEASE_S)) == []
    assert trial(db, tid).status == lc.NEEDS_REVIEW
    with db.write() as s, pytest.raises(LeaseLost):
        leases.heartbeat(s, c.lease_id, actor=WORKER, lease_seconds=LEASE_S, max_attempts=ATTEMPTS)


def test_heartbeats_keep_a_lease_alive(db, make_experiment, make_trial):
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    t0 = utcnow()
    [c] = claim(db, "sim", t0)
    now = t0
    for _ in range(4):  # a heartbeat every 0.8 lease times: two lease times and more
        now += timedelta(seconds=0.8 * LEASE_S)
        assert sweep(db, now) == 0
        with db.write() as s:
            hb = leases.heartbeat(
                s, c.lease_id, actor=WORKER, lease_seconds=LEASE_S, max_attempts=ATTEMPTS, now=now
            )
        assert hb.lease_expires_at == now + timedelta(seconds=LEASE_S)
    assert trial(db, tid).status == lc.RUNNING
    assert sweep(db, now + timedelta(seconds=LEASE_S + 1)) == 1  # the heartbeats stop
    assert trial(db, tid).status == lc.QUEUED


def test_a_retried_claim_gets_its_leases_back_and_nothing_more(db, make_experiment, make_trial):
    """The server stored a claim but its answer was lost: the worker's retry, under the same
    claim id, gets the same leases back, active ones only, and takes no other trial."""
    exp = make_experiment()
    ids = [make_trial(exp, status=lc.QUEUED) for _ in range(4)]
    t0 = utcnow()
    first = claim(db, "sim", t0, claim_id="c-1", n=2)
    assert [c.trial.id for c in first] == ids[:2]
    again = claim(db, "sim", t0 + timedelta(seconds=1), claim_id="c-1", n=2)
    assert sorted((c.lease_id, c.trial.id) for c in again) == sorted(
        (c.lease_id, c.trial.id) for c in first
    )
    assert [trial(db, i).status for i in ids] == [lc.RUNNING] * 2 + [lc.QUEUED] * 2
    assert [trial(db, i).attempts for i in ids[:2]] == [1, 1]  # no second attempt opened
    # a new claim id takes new trials; another worker's claim under the same id is its own
    assert [c.trial.id for c in claim(db, "sim", t0, claim_id="c-2")] == [ids[2]]
    assert [c.trial.id for c in claim(db, "sim", t0, claim_id="c-1", worker_id="v")] == [ids[3]]
    # once its leases are lost, a late retry gets nothing (the trials are queued for others)
    with db.write() as s:
        leases.sweep_expired(s, max_attempts=ATTEMPTS, now=t0 + timedelta(seconds=LEASE_S + 1))
    assert claim(db, "sim", t0 + timedelta(seconds=LEASE_S + 2), claim_id="c-1") == []
    assert trial(db, ids[0]).status == lc.QUEUED


def test_a_claim_id_must_be_a_short_token():
    for bad in ("", "x" * 65, "has space", "new\nline"):
        with pytest.raises(ValueError, match="claim_id"):
            ClaimIn(worker_id="w", target="sim", claim_id=bad)
