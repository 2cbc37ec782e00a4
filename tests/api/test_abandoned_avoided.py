"""Abandoned means avoided: an abandoned trial's schedule is never suggested again, and the
model learns the region was refused (a penalty the operator can see on /model)."""

from __future__ import annotations

SIM = {
    "name": "avoid",
    "task": "tip_speed",
    "levels": 3,
    "n_initial": 2,
    "sim_preset": "fast",
    "seed": 3,
}


def test_an_abandoned_schedule_is_never_suggested_again(api):
    exp = api.create_experiment(**SIM)  # the default GP method
    refused: set[str] = set()
    # in the initial design
    [t] = api.suggest(exp["id"])
    api.abandon_trial(t["id"], "the motion looked unsafe")
    refused.add(t["schedule_hash"])
    [t] = api.suggest(exp["id"])
    assert t["schedule_hash"] not in refused
    api.run_trial(t["id"])
    [t] = api.suggest(exp["id"])
    assert t["schedule_hash"] not in refused
    api.run_trial(t["id"])
    # with the GP: abandon its pick, then a run of suggestions never returns to any refused one
    for _ in range(2):
        [t] = api.suggest(exp["id"])
        assert t["schedule_hash"] not in refused
        api.abandon_trial(t["id"], "hits the table")
        refused.add(t["schedule_hash"])
    for _ in range(3):
        [t] = api.suggest(exp["id"])
        assert t["schedule_hash"] not in refused
        api.run_trial(t["id"])
    model = api.model(exp["id"])
    objectives = [x["objective"] for x in api.list_trials(exp["id"], "completed")]
    assert model["n_refused"] == 3 and model["n_observations"] == len(objectives) == 5
    assert model["refused_penalty"] < min(objectives)
