"""A server restart gives live leases a fresh lease time: workers could not heartbeat meanwhile."""

from __future__ import annotations

from datetime import timedelta

from app.db.models import Lease, Trial
from app.service import leases
from app.service import lifecycle as lc
from app.service.auth import Actor
from app.service.schemas import ClaimIn

WORKER = Actor("w", "worker")


def _claim_one(db, make_experiment, make_trial) -> tuple[int, str]:
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    with db.write() as s:
        [c] = leases.claim(
            s,
            ClaimIn(worker_id="w", target="sim", max_trials=1),
            actor=WORKER,
            lease_seconds=30,
            max_attempts=3,
        )
    assert c.trial.id == tid
    return tid, c.lease_id


def test_leases_that_lapsed_while_the_server_was_down_survive_the_restart(
    db, make_experiment, make_trial
):
    tid, lease_id = _claim_one(db, make_experiment, make_trial)
    with db.write() as s:  # the server was down for longer than the lease
        lease = s.get(Lease, lease_id)
        lease.expires_at = lease.expires_at - timedelta(seconds=120)
        restart_at = lease.expires_at + timedelta(seconds=60)
    with db.write() as s:
        assert leases.grant_restart_grace(s, lease_seconds=30, now=restart_at) == 1
    with db.write() as s:  # the first sweep after the restart expires nothing
        assert leases.sweep_expired(s, max_attempts=3, now=restart_at + timedelta(seconds=29)) == 0
    with db.read() as s:
        assert s.get(Trial, tid).status == lc.RUNNING
        assert s.get(Lease, lease_id).status == "active"
    # A worker that really died still loses the lease one lease time after the restart.
    with db.write() as s:
        assert leases.sweep_expired(s, max_attempts=3, now=restart_at + timedelta(seconds=31)) == 1
    with db.read() as s:
        assert s.get(Trial, tid).status == lc.QUEUED


def test_grace_never_shortens_a_lease(db, make_experiment, make_trial):
    _, lease_id = _claim_one(db, make_experiment, make_trial)
    with db.read() as s:
        before = s.get(Lease, lease_id).expires_at
    with db.write() as s:
        assert (
            leases.grant_restart_grace(s, lease_seconds=1, now=before - timedelta(seconds=29)) == 0
        )
    with db.read() as s:
        assert s.get(Lease, lease_id).expires_at == before


def test_a_run_trial_awaiting_its_measurement_counts_as_pending(db, make_experiment, make_trial):
    from app.service import experiments, trials

    exp_id = make_experiment(target="hardware", task="throw")
    measured = make_trial(exp_id, status=lc.COMPLETED, theta=[0.3] * 11)
    with db.write() as s:
        s.get(Trial, measured).objective = 1.5
    waiting = make_trial(exp_id, status=lc.COMPLETED, theta=[0.7] * 11)
    with db.read() as s:
        inputs = trials.optimizer_inputs(s, experiments.get_experiment(s, exp_id))
    assert inputs.observed_ids == (measured,)
    assert inputs.pending_ids == frozenset({waiting})
    assert inputs.pending.tolist() == [[0.7] * 11]
