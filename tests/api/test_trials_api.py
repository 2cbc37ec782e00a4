"""Trials over HTTP: read, measurements (idempotent, validated), fail/abandon/resolve, run,
preview, trajectory; every bad-input case gets a 4xx that says what is wrong."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from app.client import HandfulClient
from app.policy import Policy

NEW_EXP = {
    "name": "exp",
    "sim_preset": "fast",
}  # this module's experiments (see tests/conftest.py new_exp)


@pytest.fixture
def queued(api, new_exp):
    exp = new_exp(api)
    [trial] = api.suggest(exp["id"])
    return exp, trial


def test_get_trial_has_measurements_and_audit(error_of, api, queued):
    _, trial = queued
    t = api.get_trial(trial["id"])
    assert t["measurements"] == []
    assert [(a["before"], a["after"]) for a in t["audit"]] == [
        (None, "proposed"),
        ("proposed", "queued"),
    ]
    assert error_of(api.get_trial, 99_999_999).status == 404


def test_measurements_keep_every_repeat_and_give_mean_and_sem(api, queued):
    _, trial = queued
    t = api.add_measurements(
        trial["id"],
        [
            {"value": 2.0, "unit": "m/s", "note": "first"},
            {"value": 4.0, "unit": "m/s"},
        ],
    )
    assert t["status"] == "completed" and t["objective"] == 3.0
    assert t["objective_sem"] == pytest.approx(np.std([2.0, 4.0], ddof=1) / np.sqrt(2))
    assert [(m["value"], m["note"]) for m in t["stored"]] == [(2.0, "first"), (4.0, "")]
    receipt = api.add_measurements(trial["id"], [{"value": 6.0, "unit": "m/s"}])
    assert receipt["n_measurements"] == 3 and receipt["objective"] == 4.0
    assert receipt["trial_id"] == trial["id"] and receipt["status"] == "completed"
    assert [m["value"] for m in receipt["stored"]] == [6.0]
    t = api.get_trial(trial["id"])
    assert [(m["value"], m["source"], m["created_by"]) for m in t["measurements"]] == [
        (2.0, "tape", "operator"),
        (4.0, "tape", "operator"),
        (6.0, "tape", "operator"),
    ]
    assert t["measurements"][0]["note"] == "first"
    assert t["measurements"][2]["id"] == receipt["stored"][0]["id"]
    assert (t["objective"], t["n_measurements"]) == (4.0, 3)


def test_duplicate_post_is_refused_and_stores_nothing(error_of, api, queued):
    _, trial = queued
    body = [{"value": 1.5, "unit": "m/s"}]
    first = api.add_measurements(trial["id"], body, idempotency_key="k-dup-1")
    err = error_of(api.add_measurements, trial["id"], body, idempotency_key="k-dup-1")
    assert err.status == 409 and err.code == "duplicate_request" and "k-dup-1" in err.detail
    assert err.body["receipt"] == first  # the first post's reply, for a client that lost it
    err = error_of(
        api.add_measurements,
        trial["id"],
        [{"value": 9.0, "unit": "m/s"}],
        idempotency_key="k-dup-1",
    )
    assert err.status == 409 and "different request" in err.detail
    assert api.get_trial(trial["id"])["n_measurements"] == 1


class _LoseFirstReply(httpx.BaseTransport):
    """Delivers every request, but the first reply is lost on the way back (a dropped link)."""

    def __init__(self) -> None:
        self.inner = httpx.HTTPTransport()
        self.lost = 0

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        response = self.inner.handle_request(request)
        if self.lost == 0:
            response.read()
            self.lost += 1
            raise httpx.ReadError("connection reset by peer", request=request)
        return response


def test_a_retry_after_a_lost_reply_stores_once_and_gets_the_first_receipt(live_server, queued):
    _, trial = queued
    flaky = HandfulClient(
        live_server.url,
        live_server.tokens["operator"],
        retries=2,
        transport=_LoseFirstReply(),
    )
    receipt = flaky.add_measurements(trial["id"], [{"value": 2.5, "unit": "m/s"}])
    assert flaky._http._transport.lost == 1  # the first reply really was lost
    assert receipt["n_measurements"] == 1 and [m["value"] for m in receipt["stored"]] == [2.5]
    t = live_server.client("operator").get_trial(trial["id"])
    assert [m["id"] for m in t["measurements"]] == [receipt["stored"][0]["id"]]


@pytest.mark.parametrize(
    ("repeats", "words"),
    [
        ([{"value": -0.5, "unit": "m/s"}], "cannot be negative"),
        ([{"value": 1e9, "unit": "m/s"}], "plausible"),
        ([{"value": 1.0, "unit": "m"}], "objective unit 'm/s'"),
        ([{"value": 1.0, "unit": "furlongs"}], "unit"),
        ([], "repeats"),
        ([{"value": "fast", "unit": "m/s"}], "value"),
        ([{"value": 1.0, "unit": "m/s"}, {"value": -3.0, "unit": "m/s"}], "repeat 2"),
    ],
)
def test_bad_measurements_are_refused_whole(error_of, api, queued, repeats, words):
    _, trial = queued
    err = error_of(api.add_measurements, trial["id"], repeats)
    assert err.status == 422 and words in str(err.detail)
    t = api.get_trial(trial["id"])
    assert t["n_measurements"] == 0 and t["status"] == "queued"


def test_negative_distance_is_refused(error_of, api, new_exp):
    exp = new_exp(api, task="throw", objective_unit="m")
    [trial] = api.suggest(exp["id"])
    err = error_of(api.add_measurements, trial["id"], [{"value": -2.0, "unit": "m"}])
    assert err.status == 422 and "distance cannot be negative" in err.detail
    assert api.add_measurements(trial["id"], [{"value": 2.0, "unit": "m"}])["objective"] == 2.0


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_measurements_are_refused(live_server, api, queued, token):
    _, trial = queued
    r = httpx.post(
        f"{live_server.url}/api/trials/{trial['id']}/measurements",
        content='{"repeats": [{"value": ' + token + ', "unit": "m/s"}]}',
        headers={
            "Authorization": f"Bearer {live_server.tokens['operator']}",
            "Content-Type": "application/json",
            "Idempotency-Key": f"nan-{token}",
        },
    )
    assert r.status_code == 422 and "finite" in r.text
    assert api.get_trial(trial["id"])["n_measurements"] == 0


def test_measurement_needs_an_idempotency_key(live_server, queued):
    _, trial = queued
    r = httpx.post(
        f"{live_server.url}/api/trials/{trial['id']}/measurements",
        json={"repeats": [{"value": 1.0, "unit": "m/s"}]},
        headers={"Authorization": f"Bearer {live_server.tokens['operator']}"},
    )
    assert r.status_code == 422 and "Idempotency-Key" in r.json()["detail"]


def test_oversize_body_is_refused(live_server, queued):
    _, trial = queued
    big = "x" * (live_server_limit(live_server) + 10)
    r = httpx.post(
        f"{live_server.url}/api/trials/{trial['id']}/fail",
        json={"reason": big},
        headers={"Authorization": f"Bearer {live_server.tokens['operator']}"},
    )
    assert r.status_code == 413 and "larger than" in r.json()["detail"]


def live_server_limit(_server) -> int:
    from app.config import Settings

    return Settings().max_body_bytes


def test_measuring_a_pending_or_finished_trial_is_illegal(error_of, api, new_exp):
    exp = new_exp(api, target="hardware")
    [trial] = api.suggest(exp["id"])
    err = error_of(api.add_measurements, trial["id"], [{"value": 1.0, "unit": "m/s"}])
    assert err.status == 409 and "awaiting_confirmation" in err.detail
    api.abandon_trial(trial["id"], "not needed")
    err = error_of(api.add_measurements, trial["id"], [{"value": 1.0, "unit": "m/s"}])
    assert err.status == 409 and "abandoned" in err.detail


def test_fail_abandon_and_illegal_transitions(error_of, api, new_exp):
    exp = new_exp(api)
    a, b = api.suggest(exp["id"], n=2)
    t = api.fail_trial(a["id"], "the arm hit the table")
    assert t["status"] == "failed" and t["status_reason"] == "the arm hit the table"
    err = error_of(api.abandon_trial, a["id"], "x")
    assert err.status == 409 and f"trial #{a['index']} is failed" in err.detail
    t = api.abandon_trial(b["id"], "bad idea")
    assert t["status"] == "abandoned"
    err = error_of(api.fail_trial, b["id"], "x")
    assert err.status == 409 and "abandoned" in err.detail
    assert error_of(api.fail_trial, a["id"], "").status == 422  # a reason is required
    assert error_of(api.fail_trial, 99_999_999, "x").status == 404
    # abandoned trials are not pending: the optimiser is free to propose elsewhere
    assert api.get_experiment(exp["id"])["status_counts"] == {"failed": 1, "abandoned": 1}


def test_resolve_needs_review_only(error_of, api, queued):
    _, trial = queued
    err = error_of(api.resolve_trial, trial["id"], "fail", "why not")
    assert err.status == 409 and "not needs_review" in err.detail
    err = error_of(api.resolve_trial, trial["id"], "explode", "why not")
    assert err.status == 422


def test_run_simulates_and_records(error_of, api, queued):
    _, trial = queued
    t = api.run_trial(trial["id"])
    assert t["status"] == "completed" and t["has_trajectory"]
    assert t["objective"] > 0 and t["n_measurements"] == 1
    assert t["executed_theta"] == t["theta"]
    assert t["duration_s"] is not None and t["duration_s"] >= 0
    traj = api.trajectory(t["id"])
    assert len(traj["time_s"]) == len(traj["tip_speed_m_s"]) > 100
    assert max(traj["tip_speed_m_s"]) == pytest.approx(t["objective"], rel=1e-6)
    assert "qpos" in traj
    raw = api.trajectory_npz(t["id"])
    assert raw[:2] == b"PK"
    err = error_of(api.run_trial, t["id"])
    assert err.status == 409 and "completed" in err.detail


def test_run_with_a_horizon_the_simulator_cannot_run_is_422_and_leaves_it_queued(
    error_of, api, new_exp
):
    exp = new_exp(api, horizon=3)  # 5 s / 3 is not a whole number of physics steps
    [trial] = api.suggest(exp["id"])
    err = error_of(api.run_trial, trial["id"])
    assert err.status == 422 and "horizon 3" in err.detail
    assert api.get_trial(trial["id"])["status"] == "queued"


def test_run_refuses_hardware_and_missing_trajectory_is_404(error_of, api, new_exp):
    exp = new_exp(api, target="hardware")
    [trial] = api.suggest(exp["id"])
    err = error_of(api.run_trial, trial["id"])
    assert err.status == 409 and "hardware" in err.detail
    err = error_of(api.trajectory, trial["id"])
    assert err.status == 404 and "no trajectory" in err.detail


def test_preview_runs_exactly_the_trials_schedule(error_of, api, new_exp):
    exp = new_exp(api, target="hardware")
    [trial] = api.suggest(exp["id"])
    job = api.preview(trial["id"])
    assert job["status"] in ("queued", "running") and job["trajectory"] is None
    assert job["schedule_hash"] == trial["schedule_hash"]
    done = api.wait_preview(job["job_id"], timeout_s=120)
    assert done["status"] == "done", done["error"]
    assert done["progress"] == 1.0
    assert done["predicted_tip_speed"] > 0
    assert isinstance(done["bend_limit_hits"], list)
    pressures = np.asarray(done["trajectory"]["pressure_pa"])
    assert pressures.shape[1] == 12
    # exactly this trial's schedule: the same rollout in-process gives the same numbers
    from app.sim import rollout

    ref = rollout("tip_speed", np.asarray(trial["pressure_schedule_pa"]), preset="fast")
    assert done["predicted_tip_speed"] == pytest.approx(ref.max_tip_speed, rel=1e-9)
    assert done["bend_limit_hits"] == [int(j) for j in ref.bend_limit_hits]
    assert np.allclose(pressures, ref.trajectory.pressure_pa)
    assert api.get_trial(trial["id"])["status"] == "awaiting_confirmation"  # no side effect
    assert error_of(api.get_preview, "nope").status == 404
    assert error_of(api.preview, 99_999_999).status == 404


def test_confirm_binds_the_exact_schedule(error_of, api, new_exp):
    exp = new_exp(api, target="hardware")
    [trial] = api.suggest(exp["id"])
    err = error_of(api.confirm_trial, trial["id"], "0" * 64)
    assert err.status == 409 and err.code == "confirmation_mismatch"
    err = error_of(api.confirm_trial, trial["id"], "not-a-hash")
    assert err.status == 422
    t = api.preview_and_confirm(trial)
    assert t["status"] == "queued" and t["confirmed_by"] == "operator"
    assert t["confirmed_hash"] == trial["schedule_hash"] and t["confirmed_at"]
    err = error_of(api.confirm_trial, trial["id"], trial["schedule_hash"])
    assert err.status == 409 and "queued" in err.detail
    assert "trial.confirm" in [a["action"] for a in api.get_trial(trial["id"])["audit"]]
    sim = new_exp(api)
    [st] = api.suggest(sim["id"])
    assert error_of(api.confirm_trial, st["id"], st["schedule_hash"]).status == 409


def test_schedule_hash_matches_policy(api, queued):
    from app.policy import schedule_hash

    _, trial = queued
    assert trial["schedule_hash"] == schedule_hash(
        trial["pressure_schedule_pa"], trial["release_step"]
    )
    decoded = Policy(levels=3).decode(np.asarray(trial["theta"]))
    assert np.allclose(decoded.pressure_schedule_pa, trial["pressure_schedule_pa"])
