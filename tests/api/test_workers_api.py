"""Workers over HTTP: claim (atomic, behind the safety gate), heartbeat, result (idempotent
per lease), faults, executed schedules, aborts. One server for this module."""

from __future__ import annotations

import base64
import io
import sqlite3
import time

import numpy as np
import pytest

from app.client import HandfulAPIError
from app.policy import Policy, PressureLimits, schedule_hash

from ..conftest import claim_until_empty

SERVER_ENV = {"HANDFUL_LEASE_SECONDS": "60", "HANDFUL_MAX_ATTEMPTS": "2"}


@pytest.fixture(autouse=True)
def _nothing_left_queued(module_server):
    """Each test starts and ends with no claimable trial (claims take the oldest first)."""
    yield
    op = module_server.client("operator")
    for exp in op.list_experiments():
        if exp["status"] == "active":
            op.patch_experiment(exp["id"], status="archived")


NEW_EXP = {
    "name": "w",
    "sim_preset": "fast",
}  # this module's experiments (see tests/conftest.py new_exp)


def npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def test_sim_claim_heartbeat_result(error_of, op, worker, new_exp):
    exp = new_exp(op)
    [trial] = op.suggest(exp["id"])
    [c] = worker.claim("w-1", "sim", max_trials=4, claim_id="claim-1")
    assert c["trial"]["id"] == trial["id"] and c["trial"]["status"] == "running"
    assert c["experiment"]["id"] == exp["id"] and c["trial"]["attempts"] == 1
    assert worker.claim("w-2", "sim") == []  # nothing left: no trial handed out twice
    # the retry of a claim whose answer was lost: the same lease back, not a second attempt
    [again] = worker.claim("w-1", "sim", max_trials=4, claim_id="claim-1")
    assert again["lease_id"] == c["lease_id"] and again["trial"]["attempts"] == 1
    err = error_of(worker.claim, "w-1", "sim", claim_id="no spaces please")
    assert err.status == 422 and "claim_id must be 1-64 letters" in str(err.detail)
    hb = worker.heartbeat(c["lease_id"])
    assert hb["status"] == "active" and hb["lease_expires_at"] >= c["lease_expires_at"]
    traj = npz_bytes(time_s=np.linspace(0, 5, 11), tip_speed_m_s=np.full(11, 2.5))
    report = {
        "executed_pressure_schedule_pa": trial["pressure_schedule_pa"],
        "objective": 2.5,
        "trajectory_npz": traj,
        "summary": {"wall_s": 0.2},
    }
    out = worker.report_result(trial["id"], c["lease_id"], **report)
    t = out["trial"]
    assert t["status"] == "completed" and t["objective"] == 2.5 and t["has_trajectory"]
    assert t["executed_theta"] == trial["theta"]  # it ran the plan: the planned θ
    detail = op.get_trial(trial["id"])
    assert [(m["source"], m["created_by"]) for m in detail["measurements"]] == [("sim", "worker")]
    assert op.trajectory(trial["id"])["tip_speed_m_s"] == [2.5] * 11
    # idempotent per lease: the same report again gives the same reply and stores nothing
    assert worker.report_result(trial["id"], c["lease_id"], **report) == out
    assert op.get_trial(trial["id"])["n_measurements"] == 1
    err = error_of(worker.report_result, trial["id"], c["lease_id"], objective=3.0)
    assert err.status == 409 and "different result" in err.detail
    err = error_of(worker.heartbeat, c["lease_id"])
    assert err.status == 409 and err.code == "lease_lost"


def test_bad_results_are_refused_and_store_nothing(error_of, op, worker, module_server, new_exp):
    exp = new_exp(op)
    a, b = op.suggest(exp["id"], n=2)
    claims = worker.claim("w-1", "sim", max_trials=2)
    lease = {c["trial"]["id"]: c["lease_id"] for c in claims}
    cases = [
        (dict(objective=float("inf")), 422),
        (dict(objective=-1.0), 422),
        (dict(executed_pressure_schedule_pa=[[1.0] * 12] * 3), 422),
        (dict(objective=1.0, trajectory_npz=b"not an npz"), 422),
    ]
    for kwargs, status in cases:
        with pytest.raises((HandfulAPIError, ValueError)) as info:
            worker.report_result(a["id"], lease[a["id"]], **kwargs)
        if isinstance(info.value, HandfulAPIError):
            assert info.value.status == status, kwargs
    err = error_of(worker.report_result, a["id"], lease[b["id"]], objective=1.0)
    assert err.status == 422 and f"is for trial {b['id']}" in err.detail
    err = error_of(worker.report_result, a["id"], "no-such-lease", objective=1.0)
    assert err.status == 404
    t = op.get_trial(a["id"])
    assert t["status"] == "running" and t["n_measurements"] == 0 and not t["has_trajectory"]
    assert t["executed_theta"] is None
    for tid in (a["id"], b["id"]):
        worker.report_result(tid, lease[tid], fault="test over")


def test_executed_schedule_is_what_the_gp_sees(op, worker, new_exp):
    exp = new_exp(op)
    [trial] = op.suggest(exp["id"])
    [c] = worker.claim("w-1", "sim")
    policy = Policy(levels=3)
    planned = policy.decode(np.asarray(trial["theta"]))
    levels = planned.level_indices.copy()
    levels[0, 0] = (levels[0, 0] + 1) % 3
    executed = policy.schedule_from_levels(levels)
    t = worker.report_result(
        trial["id"], c["lease_id"], executed_pressure_schedule_pa=executed, objective=1.7
    )["trial"]
    assert t["executed_pressure_schedule_pa"] == executed.tolist()
    np.testing.assert_array_equal(
        policy.decode(np.asarray(t["executed_theta"])).level_indices, levels
    )
    assert t["executed_theta"] != t["theta"]
    assert op.model(exp["id"])["incumbent_theta"] == t["executed_theta"]


def test_sim_fault_fails_hardware_fault_needs_review(op, worker, new_exp):
    sim = new_exp(op)
    [st] = op.suggest(sim["id"])
    [c] = worker.claim("w-1", "sim")
    t = worker.report_result(st["id"], c["lease_id"], fault="simulation diverged")["trial"]
    assert t["status"] == "failed" and "simulation diverged" in t["status_reason"]
    hw = new_exp(op, target="hardware")
    [ht] = op.suggest(hw["id"])
    op.preview_and_confirm(ht)
    [c] = worker.claim("hw-1", "hardware")
    t = worker.report_result(ht["id"], c["lease_id"], fault="I2C bus fault on joint 2")["trial"]
    assert t["status"] == "needs_review" and "I2C" in t["status_reason"]
    # the fault came with no executed schedule: nothing is recorded as having run
    assert t["executed_pressure_schedule_pa"] is None and t["executed_theta"] is None
    t = op.resolve_trial(ht["id"], "requeue", "sensor reseated")
    assert t["status"] == "awaiting_confirmation" and t["confirmed_hash"] is None
    assert worker.claim("hw-1", "hardware") == []  # needs a fresh confirmation
    op.preview_and_confirm(ht)
    [c] = worker.claim("hw-1", "hardware")
    assert c["trial"]["attempts"] == 2
    worker.report_result(ht["id"], c["lease_id"], objective=3.2)
    assert op.get_trial(ht["id"])["status"] == "completed"


def test_hardware_gate_confirmation_and_changed_schedule(
    error_of, op, worker, module_server, new_exp
):
    hw = new_exp(op, target="hardware")
    a, b, c3 = op.suggest(hw["id"], n=3)
    assert worker.claim("hw", "hardware", max_trials=3) == []  # none confirmed
    for t in (a, b, c3):
        op.preview_and_confirm(t)
    # after the confirmation, b's schedule changes in the database (same limits) and c3's is
    # forged beyond the limits with a forged matching hash: neither may reach a worker
    policy = Policy(levels=3, limits=PressureLimits(nominal_pa=100_000.0))
    other = policy.decode(np.full(10, 0.999)).pressure_schedule_pa.tolist()
    forged = (np.asarray(c3["pressure_schedule_pa"]) + 50_000.0).tolist()
    con = sqlite3.connect(module_server.db_url.removeprefix("sqlite:///"))
    with con:
        con.execute(
            "UPDATE trials SET pressure_schedule_pa = ? WHERE id = ?",
            (str(other).replace("'", '"'), b["id"]),
        )
        con.execute(
            "UPDATE trials SET pressure_schedule_pa = ?, confirmed_hash = ? WHERE id = ?",
            (str(forged), schedule_hash(forged, None), c3["id"]),
        )
    con.close()
    claims = worker.claim("hw", "hardware", max_trials=3)
    assert [c["trial"]["id"] for c in claims] == [a["id"]]
    tb, tc = op.get_trial(b["id"]), op.get_trial(c3["id"])
    assert tb["status"] == "needs_review" and "changed after confirmation" in tb["status_reason"]
    assert tc["status"] == "needs_review" and "beyond the pressure limits" in tc["status_reason"]
    # confirming a stale hash is refused too
    err = error_of(op.confirm_trial, b["id"], b["schedule_hash"])
    assert err.status == 409
    worker.report_result(a["id"], claims[0]["lease_id"], fault="stop")


def test_executed_schedule_beyond_limits_needs_review(op, worker, new_exp):
    hw = new_exp(op, target="hardware")
    [t] = op.suggest(hw["id"])
    op.preview_and_confirm(t)
    [c] = worker.claim("hw", "hardware")
    beyond = np.asarray(t["pressure_schedule_pa"])
    beyond[3, 5] = 150_000.0
    out = worker.report_result(
        t["id"], c["lease_id"], executed_pressure_schedule_pa=beyond, objective=2.0
    )["trial"]
    assert out["status"] == "needs_review" and "beyond the limits" in out["status_reason"]
    assert out["executed_pressure_schedule_pa"][3][5] == 150_000.0


def test_abort_revokes_the_lease_and_refuses_the_late_result(error_of, op, worker, new_exp):
    exp = new_exp(op)
    [t] = op.suggest(exp["id"])
    [c] = worker.claim("w", "sim")
    op.abandon_trial(t["id"], "operator stopped it")
    err = error_of(worker.report_result, t["id"], c["lease_id"], objective=1.0)
    assert err.status == 409 and err.code == "lease_lost"
    assert "revoked" in err.detail and "late result" in err.detail
    actions = [a["action"] for a in op.get_trial(t["id"])["audit"]]
    assert "trial.abort" in actions and "lease.revoked" in actions


def test_concurrent_claims_never_hand_out_a_trial_twice(op, module_server, new_exp):
    exp = new_exp(op)
    trials = op.suggest(exp["id"], n=8)
    got = claim_until_empty(module_server, n_workers=4)
    assert sorted(got) == sorted(t["id"] for t in trials)


def test_base64_trajectory_roundtrip(op, worker, new_exp):
    exp = new_exp(op)
    [t] = op.suggest(exp["id"])
    [c] = worker.claim("w", "sim")
    arrays = {"time_s": np.arange(3.0), "qpos": np.ones((3, 4))}
    worker.report_result(t["id"], c["lease_id"], objective=1.0, trajectory_npz=npz_bytes(**arrays))
    raw = worker_npz = op.trajectory_npz(t["id"])
    with np.load(io.BytesIO(raw)) as z:
        np.testing.assert_array_equal(z["qpos"], arrays["qpos"])
    assert base64.b64encode(worker_npz)


def test_resolve_complete_needs_a_measurement_and_fail_ends_it(error_of, op, worker, new_exp):
    hw = new_exp(op, target="hardware")
    a, b = op.suggest(hw["id"], n=2)
    for t in (a, b):
        op.preview_and_confirm(t)
    claims = {c["trial"]["id"]: c["lease_id"] for c in worker.claim("hw", "hardware", 2)}
    for t in (a, b):
        worker.report_result(t["id"], claims[t["id"]], fault="tracking lost")
    err = error_of(op.resolve_trial, a["id"], "complete", "it looked fine")
    assert err.status == 409 and "no measurement" in err.detail
    op.add_measurements(a["id"], [{"value": 3.9, "unit": "m/s", "note": "high-speed video"}])
    assert op.get_trial(a["id"])["status"] == "needs_review"  # a person still decides
    t = op.resolve_trial(a["id"], "complete", "video confirms the speed")
    assert t["status"] == "completed" and t["objective"] == 3.9
    t = op.resolve_trial(b["id"], "fail", "arm slipped")
    assert t["status"] == "failed" and t["status_reason"] == "arm slipped"
    audit = op.get_trial(a["id"])["audit"]
    assert any(x["action"] == "trial.resolve" and x["actor"] == "operator" for x in audit)


def test_hardware_throw_waits_for_the_operators_tape_measure(op, worker, new_exp):
    hw = new_exp(op, target="hardware", task="throw", objective_unit="m")
    [t] = op.suggest(hw["id"])
    op.preview_and_confirm(t)
    [c] = worker.claim("hw", "hardware")
    out = worker.report_result(
        t["id"],
        c["lease_id"],
        executed_pressure_schedule_pa=t["pressure_schedule_pa"],
        executed_release_step=t["release_step"],
    )["trial"]
    assert out["status"] == "completed" and out["objective"] is None
    assert "awaiting the operator's measurement" in out["status_reason"]
    measured = op.add_measurements(
        t["id"], [{"value": 2.4, "unit": "m", "note": "tape"}, {"value": 2.6, "unit": "m"}]
    )
    assert measured["objective"] == pytest.approx(2.5) and measured["n_measurements"] == 2


def test_a_small_upload_of_a_huge_array_is_refused_before_the_lock(
    error_of, op, worker, module_server, new_exp
):
    exp = new_exp(op)
    [t] = op.suggest(exp["id"])
    [c] = worker.claim("w", "sim")
    buf = io.BytesIO()
    np.savez_compressed(buf, tip_speed_m_s=np.zeros(16 * 1024 * 1024))  # 128 MB in ~125 KB
    lock = sqlite3.connect(module_server.data_dir / "handful.db", isolation_level=None)
    lock.execute("BEGIN IMMEDIATE")  # another program holds the write lock meanwhile
    try:
        t0 = time.perf_counter()
        err = error_of(worker.report_result, t["id"], c["lease_id"], trajectory_npz=buf.getvalue())
        elapsed = time.perf_counter() - t0
    finally:
        lock.rollback()
        lock.close()
    assert err.status == 413 and "at most 50000 samples" in err.detail
    assert elapsed < 5  # checked before waiting for the database
    trial = op.get_trial(t["id"])
    assert trial["status"] == "running" and not trial["has_trajectory"]
    worker.report_result(t["id"], c["lease_id"], objective=1.0)  # the lease still holds


def test_a_ragged_executed_schedule_is_422_and_the_lease_holds(op, worker, module_server, new_exp):
    import httpx

    exp = new_exp(op)
    [t] = op.suggest(exp["id"])
    [c] = worker.claim("w", "sim")
    ragged = [[0.0] * 12] * 9 + [[0.0] * 11]
    r = httpx.post(
        f"{module_server.url}/api/trials/{t['id']}/result",
        json={"lease_id": c["lease_id"], "executed_pressure_schedule_pa": ragged},
        headers={"Authorization": f"Bearer {module_server.tokens['worker']}"},
        timeout=30,
    )
    assert r.status_code == 422 and "row 9 has 11 pressures" in r.text
    assert op.get_trial(t["id"])["status"] == "running"
    worker.report_result(t["id"], c["lease_id"], objective=1.0)
