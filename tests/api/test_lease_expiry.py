"""Lost leases over HTTP: the server's background sweep requeues a dead worker's trial with no
worker call, and a late result or heartbeat gets 409 lease_lost. Short leases on this module's
server. (The rules, on the service's clock without sleeping: tests/service/test_leases.py.)"""

from __future__ import annotations

import time

import pytest

from app.client import HandfulAPIError

SERVER_ENV = {"HANDFUL_LEASE_SECONDS": "1.5", "HANDFUL_MAX_ATTEMPTS": "2"}


NEW_EXP = {"name": "lease"}  # this module's experiments (see tests/conftest.py new_exp)


def wait_status(op, trial_id, status, timeout_s=20.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        t = op.get_trial(trial_id)
        if t["status"] == status:
            return t
        time.sleep(0.2)
    raise AssertionError(f"trial {trial_id} is {t['status']}, not {status}: {t['status_reason']}")


def test_the_background_sweep_requeues_a_dead_workers_trial(op, worker, new_exp):
    exp = new_exp(op)
    [t] = op.suggest(exp["id"])
    [c1] = worker.claim("w-dead", "sim")
    t1 = wait_status(op, t["id"], "queued")  # the background sweep, no worker call needed
    assert "attempt 1/2" in t1["status_reason"] and "stopped heartbeating" in t1["status_reason"]
    with pytest.raises(HandfulAPIError) as info:
        worker.report_result(t["id"], c1["lease_id"], objective=1.0)
    assert info.value.status == 409 and info.value.code == "lease_lost"
    assert "expired" in info.value.detail and "late result" in info.value.detail
    with pytest.raises(HandfulAPIError) as info:
        worker.heartbeat(c1["lease_id"])
    assert info.value.code == "lease_lost"
    op.patch_experiment(exp["id"], status="archived")
