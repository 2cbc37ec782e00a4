"""What needs the operator, per experiment: trials awaiting confirmation and measurement,
the budget reached; and the form rules the API checks (n_initial vs budget, budget vs trials)."""

from __future__ import annotations


def test_counts_of_what_awaits_the_operator_and_the_budget(error_of, hw_exp, api, worker_api):
    exp = hw_exp(api, name="queue", budget=2)
    a, b = api.suggest(exp["id"], n=2)
    listed = {e["id"]: e for e in api.list_experiments()}[exp["id"]]
    assert listed["status_counts"] == {"awaiting_confirmation": 2}
    assert listed["n_awaiting_measurement"] == 0
    assert listed["budget_reached"] is True and listed["n_budget_used"] == 2
    api.preview_and_confirm(a)
    [claim] = worker_api.claim("hw", "hardware")
    worker_api.report_result(a["id"], claim["lease_id"], objective=3.0)  # the tracker's value
    e = api.get_experiment(exp["id"])
    assert e["n_awaiting_measurement"] == 1  # the tape has not spoken
    assert e["status_counts"] == {"awaiting_confirmation": 1, "completed": 1}
    api.add_measurements(a["id"], [{"value": 1.3, "unit": "m"}])
    assert api.get_experiment(exp["id"])["n_awaiting_measurement"] == 0
    api.abandon_trial(b["id"], "not today")
    e = api.get_experiment(exp["id"])
    assert e["budget_reached"] is False and e["best_trial_index"] == a["index"]
    # the budget cannot go below the trials the experiment has
    err = error_of(api.patch_experiment, exp["id"], budget=0)
    assert err.status == 422
    api.suggest(exp["id"])
    err = error_of(api.patch_experiment, exp["id"], budget=1)
    assert err.status == 422 and "below the 2 trials" in err.detail


def test_n_initial_must_fit_in_the_budget(error_of, api):
    err = error_of(api.create_experiment, name="x", task="throw", levels=3, budget=5)
    assert err.status == 422 and "12 random initial trials" in err.detail
    assert "budget of 5" in err.detail
