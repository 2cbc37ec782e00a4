"""Lost leases: a sim trial is requeued up to max_attempts then failed; a hardware trial goes
to needs_review and is never rerun on its own; a late result is refused; heartbeats keep a
lease alive. Short leases on this module's server (expiry swept on a 0.5 s timer)."""

from __future__ import annotations

import time

import pytest

from app.client import HandfulAPIError

SERVER_ENV = {"HANDFUL_LEASE_SECONDS": "1.5", "HANDFUL_MAX_ATTEMPTS": "2"}


@pytest.fixture
def op(module_server):
    return module_server.client("operator")


@pytest.fixture
def worker(module_server):
    return module_server.client("worker")


def new_exp(op, **fields):
    spec = {"name": "lease", "task": "tip_speed", "levels": 3, "method": "random", **fields}
    return op.create_experiment(**spec)


def wait_status(op, trial_id, status, timeout_s=20.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        t = op.get_trial(trial_id)
        if t["status"] == status:
            return t
        time.sleep(0.2)
    raise AssertionError(f"trial {trial_id} is {t['status']}, not {status}: {t['status_reason']}")


def test_sim_trial_is_requeued_then_failed(op, worker):
    exp = new_exp(op)
    [t] = op.suggest(exp["id"])
    [c1] = worker.claim("w-dead", "sim")
    t1 = wait_status(op, t["id"], "queued")  # the background sweep, no worker call needed
    assert "attempt 1/2" in t1["status_reason"] and "stopped heartbeating" in t1["status_reason"]
    with pytest.raises(HandfulAPIError) as info:
        worker.report_result(t["id"], c1["lease_id"], objective=1.0)
    assert info.value.status == 409 and info.value.code == "lease_lost"
    assert "expired" in info.value.detail and "late result" in info.value.detail
    [c2] = worker.claim("w-dead-2", "sim")
    assert c2["trial"]["id"] == t["id"] and c2["trial"]["attempts"] == 2
    t2 = wait_status(op, t["id"], "failed")
    assert "2 attempts" in t2["status_reason"]
    assert op.get_trial(t["id"])["n_measurements"] == 0
    op.patch_experiment(exp["id"], status="archived")


def test_hardware_trial_goes_to_needs_review_and_stays(op, worker):
    exp = new_exp(op, target="hardware", limits={"nominal_pa": 100_000.0})
    [t] = op.suggest(exp["id"])
    op.preview_and_confirm(t)
    [c] = worker.claim("hw-dead", "hardware")
    tr = wait_status(op, t["id"], "needs_review")
    assert "never rerun on its own" in tr["status_reason"]
    time.sleep(2.0)
    assert worker.claim("hw-2", "hardware") == []
    assert op.get_trial(t["id"])["status"] == "needs_review"
    with pytest.raises(HandfulAPIError) as info:
        worker.heartbeat(c["lease_id"])
    assert info.value.code == "lease_lost"
    op.patch_experiment(exp["id"], status="archived")


def test_heartbeats_keep_a_lease_alive(op, worker):
    exp = new_exp(op)
    [t] = op.suggest(exp["id"])
    [c] = worker.claim("w-alive", "sim")
    deadline = time.monotonic() + 4.0
    while time.monotonic() < deadline:
        worker.heartbeat(c["lease_id"])
        time.sleep(0.3)
    assert op.get_trial(t["id"])["status"] == "running"
    out = worker.report_result(t["id"], c["lease_id"], objective=2.0)
    assert out["trial"]["status"] == "completed"
    op.patch_experiment(exp["id"], status="archived")
