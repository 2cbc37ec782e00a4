"""Drift checks through the API: a reference θ every k hardware trials (the schedule, the
frozen incumbent, outside the budget), bad settings refused in words, and the band: a shift
beyond it warns and is audited, a score within it does neither."""

from __future__ import annotations

import pytest

from app.client import HandfulAPIError

HW = {
    "name": "drift",
    "task": "tip_speed",
    "target": "hardware",
    "levels": 3,
    "method": "random",
    "sim_preset": "fast",
    "limits": {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0},
}


def error_of(call, *args, **kwargs) -> HandfulAPIError:
    with pytest.raises(HandfulAPIError) as info:
        call(*args, **kwargs)
    return info.value


def score(api, trial: dict, value: float) -> dict:
    """Preview, confirm and measure a hardware trial (the tracker's speed, m/s)."""
    api.preview_and_confirm(trial)
    api.add_measurements(trial["id"], [{"value": value, "unit": "m/s"}])
    return api.get_trial(trial["id"])


def test_a_reference_lands_every_k_hardware_trials_outside_the_budget(api):
    exp = api.create_experiment(**HW, budget=6, reference={"every": 3})
    assert exp["reference"]["theta_from"] == "incumbent" and exp["reference"]["theta"] is None
    scores = iter([1.0, 1.5, 1.2, 2.5, 1.1, 1.0, 1.0, 1.0])
    made = []
    while len([t for t in made if t["source"] != "reference"]) < 6:
        batch = api.suggest(exp["id"])
        made += batch
        for t in batch:
            score(api, t, next(scores))
    trials = api.list_trials(exp["id"])
    assert [t["source"] for t in trials] == ["optimizer", "optimizer", "reference"] * 2 + [
        "optimizer",
        "optimizer",
    ]
    refs = [t for t in trials if t["source"] == "reference"]
    # the incumbent when the first reference was made (trial 2, 1.5 m/s), frozen: trial 4
    # scored 2.5 since, yet the second reference repeats trial 2's θ
    assert refs[0]["theta"] == refs[1]["theta"] == trials[1]["theta"]
    assert all(r["status"] == "completed" and r["confirmed_by"] for r in refs)  # gated
    exp = api.get_experiment(exp["id"])
    assert exp["reference"]["trial_id"] == trials[1]["id"]
    assert (exp["n_budget_used"], exp["n_reference_trials"], exp["budget_reached"]) == (6, 2, True)
    err = error_of(api.suggest, exp["id"])
    assert err.status == 409 and "budget" in err.detail
    frozen = [a for a in api.audit(exp["id"]) if a["action"] == "experiment.reference_frozen"]
    assert len(frozen) == 1 and frozen[0]["trial_id"] == trials[1]["id"]
    drift = api.drift(exp["id"])
    assert [p["index"] for p in drift["points"]] == [3, 6]
    assert drift["band"] is None and "once 3 references are scored (2 so far)" in drift["message"]


def test_references_within_one_suggestion_and_an_abandoned_reference_pauses_them(api):
    exp = api.create_experiment(**HW)
    [first] = api.suggest(exp["id"])  # not yet scored: a chosen trial needs no score
    out = api.set_reference(exp["id"], every=2, theta_from="trial", trial_index=first["index"])
    assert out["reference"]["theta"] == first["theta"] and out["next_reference_in"] == 0
    made = api.suggest(exp["id"], n=2)
    assert [t["source"] for t in made] == ["reference", "optimizer", "reference", "optimizer"]
    assert [t["index"] for t in made] == [2, 3, 4, 5]
    assert made[0]["status"] == "awaiting_confirmation" and made[0]["theta"] == first["theta"]
    assert made[0]["predicted_mean"] is None  # not an optimiser suggestion
    # the operator refuses the reference's schedule: no more references of it
    api.abandon_trial(made[0]["id"], "the reference swings too close to the table")
    api.abandon_trial(made[2]["id"], "the same")
    assert "abandoned" in api.drift(exp["id"])["message"]
    assert [t["source"] for t in api.suggest(exp["id"])] == ["optimizer"]


def test_bad_reference_and_age_settings_are_refused_in_words(api):
    before = len(api.list_experiments())
    for every in (1, 0, -3):
        err = error_of(api.create_experiment, **HW, reference={"every": every})
        assert err.status == 422 and "k must be at least 2" in err.detail, err.detail
    err = error_of(api.create_experiment, **{**HW, "target": "sim"}, reference={"every": 3})
    assert err.status == 422 and "hardware experiments" in err.detail
    err = error_of(
        api.create_experiment, **HW, reference={"every": 3, "theta_from": "trial", "trial_index": 1}
    )
    assert err.status == 422 and "no trials to choose from" in err.detail
    err = error_of(api.create_experiment, **HW, age_halflife_trials=10.0)
    assert err.status == 422 and "random has no GP" in err.detail
    err = error_of(
        api.create_experiment,
        **{**HW, "method": "bo-lei-default"},
        optimizer_settings={"age_halflife_trials": 10.0},
    )
    assert err.status == 422 and "the experiment's own field" in err.detail
    err = error_of(api.create_experiment, **{**HW, "method": "bo-lei"}, age_halflife_trials=-1.0)
    assert err.status == 422
    assert len(api.list_experiments()) == before  # nothing stored

    exp = api.create_experiment(**HW)
    for body, words in [
        ({"every": 1}, "k must be at least 2"),
        ({"every": 3, "theta_from": "trial"}, "give the number of the trial"),
        ({"every": 3, "theta_from": "trial", "trial_index": 7}, "has no trial 7"),
        ({"every": 3, "trial_index": 1}, "only with theta_from = trial"),
    ]:
        err = error_of(api.set_reference, exp["id"], **body)
        assert err.status == 422 and words in str(err.detail), (body, err.detail)
    err = error_of(api.set_reference, exp["id"], every=3, baseline_n=1)
    assert err.status == 422  # the band needs at least 2 references
    assert api.get_experiment(exp["id"])["reference"] is None
    err = error_of(api.patch_experiment, exp["id"], age_halflife_trials=5.0)
    assert err.status == 422 and "random has no GP" in err.detail


def test_a_shift_beyond_the_band_warns_and_is_audited_a_score_within_does_neither(api):
    exp = api.create_experiment(**HW)
    [first] = api.suggest(exp["id"])
    score(api, first, 1.0)
    api.set_reference(exp["id"], every=2, theta_from="trial", trial_index=1, baseline_n=3)
    refs = []

    def next_reference(value: float) -> dict:
        ref, ordinary = api.suggest(exp["id"])
        assert ref["source"] == "reference"
        refs.append(score(api, ref, value))
        score(api, ordinary, 0.5)
        return api.drift(exp["id"])

    for v in (1.00, 1.04, 0.96):  # the baseline: mean 1.00, std 0.04: band 1.00 ± 0.08
        drift = next_reference(v)
    assert drift["band"]["center"] == pytest.approx(1.0)
    assert drift["band"]["half_width"] == pytest.approx(0.08)
    drift = next_reference(1.05)  # within the band
    assert not drift["shifted"] and drift["warning"] == ""
    assert [p["outside"] for p in drift["points"]] == [False] * 4

    def drift_audit() -> list[dict]:
        return [a for a in api.audit(exp["id"]) if a["action"].startswith("drift.")]

    assert drift_audit() == []
    drift = next_reference(0.70)  # the robot changed
    assert drift["shifted"] and drift["points"][-1]["outside"]
    assert f"reference trial {refs[-1]['index']} scored 0.7 m/s" in drift["warning"]
    [shift] = drift_audit()
    assert (shift["action"], shift["trial_id"], shift["actor"]) == (
        "drift.shift",
        refs[-1]["id"],
        "service",
    )
    assert shift["detail"]["objective"] == pytest.approx(0.7)
    assert shift["detail"]["center"] == pytest.approx(1.0)
    # a typo, corrected: back in the band, and the log says so
    typo = refs[-1]["measurements"][0]
    api.supersede_measurement(typo["id"], 1.01, "m/s", "typed 0.70 for 1.01")
    drift = api.drift(exp["id"])
    assert not drift["shifted"] and drift["warning"] == ""
    assert [a["action"] for a in drift_audit()] == ["drift.back_in_band", "drift.shift"]
    # a narrower band (± 0.03 m/s): the 4th reference (1.05) is now beyond it, the 5th not
    drift = api.set_reference(
        exp["id"], every=2, theta_from="trial", trial_index=1, baseline_n=3, tolerance=0.03
    )
    assert [p["outside"] for p in drift["points"]] == [False, False, False, True, False]
    assert not drift["shifted"]  # the latest is within
    audit = drift_audit()
    assert (audit[0]["action"], audit[0]["trial_id"]) == ("drift.shift", refs[3]["id"])
    assert len(audit) == 3
