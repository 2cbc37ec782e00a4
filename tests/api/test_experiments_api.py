"""Experiments over HTTP: every route's success and its bad-input cases."""

from __future__ import annotations

import csv
import io
import json
import math

import httpx
import pytest


def test_create_get_list_patch(api, new_exp):
    exp = new_exp(api, name="throwing", task="throw", levels=5, budget=30, notes="first")
    assert exp["with_release"] is True and exp["dim"] == 11 and exp["n_initial"] == 12
    assert exp["status"] == "active" and exp["created_by"] == "operator"
    assert exp["objective_unit"] == "score"
    assert exp["command_hold"] == "zero"  # the default: each row held for its step
    assert api.get_experiment(exp["id"]) == exp
    ramped = new_exp(api, task="throw", command_hold="linear")
    assert api.get_experiment(ramped["id"])["command_hold"] == "linear"
    assert exp["id"] in [e["id"] for e in api.list_experiments()]
    out = api.patch_experiment(exp["id"], status="paused", notes="later", budget=40)
    assert (out["status"], out["notes"], out["budget"]) == ("paused", "later", 40)
    assert out["version"] > exp["version"]
    actions = {a["action"] for a in api.audit(exp["id"])}
    assert {"experiment.create", "experiment.status", "experiment.budget"} <= actions


def test_create_hardware_experiment_keeps_its_limits(api, new_exp):
    exp = new_exp(
        api,
        target="hardware",
        limits={"nominal_pa": [110_000.0] * 12, "max_step_pa": 25_000.0, "source_pa": 200_000.0},
    )
    assert exp["limits"] == {
        "nominal_pa": [110_000.0] * 12,
        "max_step_pa": 25_000.0,
        "source_pa": 200_000.0,
    }


@pytest.mark.parametrize(
    ("fields", "status", "words"),
    [
        ({"task": "juggle"}, 422, "task"),
        ({"levels": 1}, 422, "levels"),
        ({"horizon": 0}, 422, "horizon"),
        ({"method": "gradient-descent"}, 422, "gradient-descent"),
        ({"target": "hardware", "limits": None}, 422, "limits"),  # new_exp adds limits otherwise
        ({"limits": {"nominal_pa": 10_000.0, "max_step_pa": 30_000.0}}, 422, "outside"),
        ({"limits": {"nominal_pa": [1.0, 2.0]}}, 422, "12 values"),
        ({"seed": -1}, 422, "seed"),
        ({"budget": 0}, 422, "budget"),
        ({"surprise": 1}, 422, "surprise"),
        ({"sim_preset": "nope"}, 422, "sim_preset"),
        ({"command_hold": "cubic"}, 422, "command_hold"),
        ({"optimizer_settings": {"colour": "red"}}, 422, "colour"),
    ],
)
def test_create_refuses_bad_input(error_of, api, fields, status, words, new_exp):
    err = error_of(new_exp, api, **fields)
    assert err.status == status
    assert words in json.dumps(err.detail)


def test_create_refuses_nan_and_infinity(live_server):
    body = '{"name": "x", "task": "tip_speed", "levels": 3, "kappa": NaN}'
    r = httpx.post(
        live_server.url + "/api/experiments",
        content=body,
        headers={
            "Authorization": f"Bearer {live_server.tokens['operator']}",
            "Content-Type": "application/json",
        },
    )
    assert r.status_code == 422
    assert "kappa" in r.text


def test_unknown_ids_are_404(error_of, api):
    for call in (api.get_experiment, api.list_trials, api.model, api.version, api.export):
        err = error_of(call, 987_654)
        assert err.status == 404 and "experiment 987654 not found" in err.detail
    assert error_of(api.suggest, 987_654).status == 404
    assert error_of(api.patch_experiment, 987_654, notes="x").status == 404


def test_suggest_queues_sim_trials_and_respects_budget_and_status(error_of, api, new_exp):
    exp = new_exp(api, budget=3)
    trials = api.suggest(exp["id"], n=2)
    assert [t["index"] for t in trials] == [1, 2]
    assert all(t["status"] == "queued" and t["source"] == "optimizer" for t in trials)
    assert all(len(t["theta"]) == 10 and len(t["pressure_schedule_pa"]) == 10 for t in trials)
    assert all(0 <= v <= 1 for t in trials for v in t["theta"])
    err = error_of(api.suggest, exp["id"], n=2)
    assert err.status == 409 and "budget of 3" in err.detail
    api.patch_experiment(exp["id"], status="paused")
    err = error_of(api.suggest, exp["id"], n=1)
    assert err.status == 409 and "paused" in err.detail
    assert error_of(api.suggest, exp["id"], n=0).status == 422


def test_hardware_suggestions_await_confirmation(api, new_exp):
    exp = new_exp(api, target="hardware")
    [trial] = api.suggest(exp["id"])
    assert trial["status"] == "awaiting_confirmation"
    sched = trial["pressure_schedule_pa"]
    assert all(70_000.0 - 1e-6 <= p <= 130_000.0 + 1e-6 for row in sched for p in row)


def test_bo_suggestion_stores_predicted_mean_and_std(api, new_exp):
    exp = new_exp(
        api, method="bo-lei", n_initial=2, optimizer_settings={"num_restarts": 2, "raw_samples": 64}
    )
    api.import_observations(
        exp["id"],
        [
            {"theta": [0.1] * 10, "objective": 1.0},
            {"theta": [0.9] * 10, "objective": 2.0},
            {"theta": [0.5] * 10, "objective": 1.5},
        ],
    )
    [trial], timing = api.suggest_timed(exp["id"])
    assert 0 < timing["optimizer"] <= timing["total"]
    assert trial["predicted_mean"] is not None and math.isfinite(trial["predicted_mean"])
    assert trial["predicted_std"] is not None and trial["predicted_std"] >= 0
    model = api.model(exp["id"])
    assert model["n_observations"] == 3
    assert len(model["lengthscales"]) == 10
    assert model["incumbent_theta"] == [0.9] * 10 and model["incumbent_objective"] == 2.0
    assert len(model["slices"]) == 10
    s0 = model["slices"][0]
    assert len(s0["theta"]) == len(s0["mean"]) == len(s0["std"])


def test_model_before_data_and_without_a_surrogate(api, new_exp):
    exp = new_exp(api)
    assert api.model(exp["id"])["slices"] == []
    api.import_observations(exp["id"], [{"theta": [0.2] * 10, "objective": 0.5}])
    m = api.model(exp["id"])
    assert m["incumbent_objective"] == 0.5 and m["lengthscales"] is None


def test_attach_checks_theta(error_of, api, new_exp):
    exp = new_exp(api)
    t = api.attach_trial(exp["id"], [0.25] * 10, note="my guess")
    assert t["source"] == "operator" and t["note"] == "my guess" and t["status"] == "queued"
    err = error_of(api.attach_trial, exp["id"], [0.5] * 9)
    assert err.status == 422 and "10 entries" in err.detail
    err = error_of(api.attach_trial, exp["id"], [0.5] * 9 + [1.5])
    assert err.status == 422 and "outside [0, 1]" in err.detail
    err = error_of(api.attach_trial, exp["id"], [0.5] * 9 + [-0.1])
    assert err.status == 422
    assert len(api.list_trials(exp["id"])) == 1  # nothing stored half


def test_import_is_all_or_nothing(error_of, api, new_exp):
    exp = new_exp(api)
    good = {"theta": [0.3] * 10, "objective": 1.2}
    err = error_of(
        api.import_observations, exp["id"], [good, {"theta": [0.3] * 10, "objective": -1.0}]
    )
    assert err.status == 422 and "negative" in err.detail
    err = error_of(
        api.import_observations, exp["id"], [good, {"theta": [2.0] * 10, "objective": 1.0}]
    )
    assert err.status == 422 and "observations[1]" in err.detail
    assert api.list_trials(exp["id"]) == []
    trials = api.import_observations(exp["id"], [good, {**good, "objective_sem": 0.1}])
    assert [t["status"] for t in trials] == ["completed", "completed"]
    assert trials[1]["objective_sem"] == 0.1 and trials[0]["source"] == "import"


def test_export_csv_and_json(error_of, api, new_exp):
    exp = new_exp(api)
    api.import_observations(exp["id"], [{"theta": [0.3] * 10, "objective": 1.25}])
    api.suggest(exp["id"], n=1)
    rows = list(csv.DictReader(io.StringIO(api.export(exp["id"], "csv"))))
    assert [r["status"] for r in rows] == ["completed", "queued"]
    assert float(rows[0]["objective"]) == 1.25 and float(rows[0]["theta_0"]) == 0.3
    assert {r["command_hold"] for r in rows} == {"zero"}
    assert rows[0]["created_by"] == "operator"
    assert rows[0]["repeats"] == "1.25 m/s imported by operator"
    data = api.export(exp["id"], "json")
    assert data["experiment"]["id"] == exp["id"] and data["experiment"]["command_hold"] == "zero"
    assert len(data["trials"]) == 2 and len(data["measurements"]) == 1
    err = error_of(api.export, exp["id"], "xml")
    assert err.status == 422
    everything = api.export(exp["id"], "bundle")  # trajectories and the audit log too
    assert everything["format"] == "handful-experiment-bundle"
    assert {"trial.import", "experiment.create"} <= {a["action"] for a in everything["audit"]}


def test_version_changes_on_every_change(api, new_exp):
    exp = new_exp(api)
    v0 = api.version(exp["id"])
    [t] = api.suggest(exp["id"])
    v1 = api.version(exp["id"])
    api.add_measurements(t["id"], [{"value": 1.0, "unit": "m/s"}])
    v2 = api.version(exp["id"])
    assert v0 < v1 < v2
    assert api.version(exp["id"]) == v2  # reading changes nothing


def test_no_route_takes_a_token_in_its_url(live_server, api, new_exp):
    """Tokens travel only in the Authorization header (URLs end up in access logs)."""
    exp = new_exp(api)
    base = f"{live_server.url}/api/experiments/{exp['id']}"
    token = live_server.tokens["viewer"]
    assert httpx.get(f"{base}/version?token={token}").status_code == 401
    assert httpx.get(f"{base}/events?token={token}").status_code == 404  # no SSE: poll /version
    paths = httpx.get(live_server.url + "/openapi.json").json()["paths"]
    assert not any(p.endswith("/events") for p in paths)


def test_openapi_docs_and_health(live_server):
    docs = httpx.get(live_server.url + "/docs")
    assert docs.status_code == 200
    # served from the installed package: nothing from a CDN (the page works offline)
    assert "cdn." not in docs.text and "/docs-assets/swagger-ui-bundle.js" in docs.text
    for asset in ("swagger-ui-bundle.js", "swagger-ui.css"):
        assert httpx.get(f"{live_server.url}/docs-assets/{asset}").status_code == 200
    paths = httpx.get(live_server.url + "/openapi.json").json()["paths"]
    for path in (
        "/api/experiments/{experiment_id}/suggest",
        "/api/workers/claim",
        "/api/trials/{trial_id}/confirm",
        "/api/previews/{job_id}",
    ):
        assert path in paths
    health = httpx.get(live_server.url + "/health").json()
    assert (health["status"], health["db"]) == ("ok", "ok") and health["version"]
