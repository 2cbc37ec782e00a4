"""No trial stays ``running`` for ever (issue 16, finding 3): a run in the service holds a
lease, a run that fails ends failed with the reason, and a running trial that nothing runs is
swept. Time moves through the service's ``now=`` arguments, not sleeps."""

from __future__ import annotations

from datetime import timedelta

import pytest

from app.db.base import utcnow
from app.db.models import Lease, Trial
from app.service import leases, runs
from app.service import lifecycle as lc
from app.service.errors import InvalidInput

from .conftest import OPERATOR


def test_a_horizon_the_simulator_cannot_run_is_refused_and_the_trial_stays_queued(
    db, make_experiment, make_trial, tmp_path
):
    tid = make_trial(make_experiment(horizon=3), status=lc.QUEUED)  # 5 s / 3: not whole ms
    with pytest.raises(InvalidInput, match="horizon 3"):
        runs.run_trial(db, tid, actor=OPERATOR, artifacts_dir=tmp_path)
    with db.read() as s:
        trial = s.get(Trial, tid)
        assert trial.status == lc.QUEUED and trial.attempts == 0
        assert s.query(Lease).filter_by(trial_id=tid).count() == 0


def test_a_service_run_holds_a_lease_and_a_dead_server_leaves_it_failed(
    db, make_experiment, make_trial
):
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    t0 = utcnow()
    with db.write() as s:  # the server starts the run ... and dies before finishing it
        run = runs.start_run(s, tid, actor=OPERATOR, lease_seconds=30, now=t0)
    with db.read() as s:
        lease = s.get(Lease, run.lease_id)
        assert s.get(Trial, tid).status == lc.RUNNING
        assert lease.status == "active" and lease.worker_id == leases.SERVICE_WORKER
    with db.write() as s:  # a restart gives worker leases grace, not the dead server's run
        assert leases.grant_restart_grace(s, lease_seconds=30, now=t0 + timedelta(seconds=5)) == 0
    with db.write() as s:  # while the lease lasts, nothing happens
        assert leases.sweep_expired(s, max_attempts=3, now=t0 + timedelta(seconds=29)) == 0
    with db.write() as s:
        assert leases.sweep_expired(s, max_attempts=3, now=t0 + timedelta(seconds=31)) == 1
    with db.read() as s:
        trial = s.get(Trial, tid)
        assert trial.status == lc.FAILED  # not requeued: it was started by hand
        assert "server stopped while simulating it" in trial.status_reason


def test_a_renewed_service_run_is_not_swept_and_finishes(db, make_experiment, make_trial, tmp_path):
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    t0 = utcnow()
    with db.write() as s:
        run = runs.start_run(s, tid, actor=OPERATOR, lease_seconds=30, now=t0)
    with db.write() as s:
        assert runs.renew_run(s, run, lease_seconds=30, now=t0 + timedelta(seconds=20))
    with db.write() as s:
        assert leases.sweep_expired(s, max_attempts=3, now=t0 + timedelta(seconds=45)) == 0
    with db.write() as s:
        out = runs.finish_run(
            s,
            run,
            None,
            "the simulator failed: RuntimeError: boom",
            actor=OPERATOR,
            artifacts_dir=tmp_path,
        )
    assert out.status == lc.FAILED and "RuntimeError: boom" in out.status_reason
    with db.read() as s:
        assert s.get(Lease, run.lease_id).status == "completed"


def test_an_aborted_service_run_stops_renewing(db, make_experiment, make_trial):
    from app.service import trials

    tid = make_trial(make_experiment(), status=lc.QUEUED)
    with db.write() as s:
        run = runs.start_run(s, tid, actor=OPERATOR, lease_seconds=30)
    with db.write() as s:
        trials.fail(s, tid, "operator stopped it", actor=OPERATOR)
    with db.write() as s:
        assert not runs.renew_run(s, run, lease_seconds=30)


def test_a_simulator_crash_ends_failed_with_the_reason(
    db, make_experiment, make_trial, tmp_path, monkeypatch
):
    import app.sim

    def crash(*_a, **_k):
        raise RuntimeError("MuJoCo ran out of memory")

    monkeypatch.setattr(app.sim, "rollout", crash)  # the fault is injected, the rest is real
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    out = runs.run_trial(db, tid, actor=OPERATOR, artifacts_dir=tmp_path, lease_seconds=30)
    assert out.status == lc.FAILED
    assert "RuntimeError: MuJoCo ran out of memory" in out.status_reason


@pytest.mark.parametrize(("target", "ends"), [("sim", lc.FAILED), ("hardware", lc.NEEDS_REVIEW)])
def test_a_running_trial_without_any_lease_is_swept(db, make_experiment, make_trial, target, ends):
    tid = make_trial(make_experiment(target=target), status=lc.RUNNING)
    with db.read() as s:
        since = s.get(Trial, tid).updated_at
    with db.write() as s:
        assert leases.sweep_expired(s, max_attempts=3, now=since + timedelta(seconds=59)) == 0
    with db.write() as s:
        assert leases.sweep_expired(s, max_attempts=3, now=since + timedelta(seconds=61)) == 1
    with db.read() as s:
        trial = s.get(Trial, tid)
        assert trial.status == ends and "no lease" in trial.status_reason
