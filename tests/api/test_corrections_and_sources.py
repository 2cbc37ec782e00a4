"""Measurements: corrections with history (withdraw / supersede, nothing deleted) and
sources kept apart (tape, tracker, sim, imported; the experiment picks the objective's)."""

from __future__ import annotations

import pytest


def tape(*values: float, source: str = "tape") -> list[dict]:
    return [{"value": v, "unit": "m", "source": source} for v in values]


def measured(api, exp_id: int, *values: float) -> dict:
    [t] = api.suggest(exp_id)
    api.preview_and_confirm(t)
    api.add_measurements(t["id"], tape(*values))
    return api.get_trial(t["id"])


def test_a_typo_is_superseded_and_a_repeat_withdrawn_with_history(error_of, hw_exp, api):
    exp = hw_exp(api)
    a = measured(api, exp["id"], 1.0, 1.2)
    b = measured(api, exp["id"], 2.0, 12.9)  # 12.9 typed for 1.29
    assert b["objective"] == pytest.approx(7.45)
    model = api.model(exp["id"])
    assert model["incumbent_objective"] == pytest.approx(7.45)
    typo = b["measurements"][1]
    out = api.supersede_measurement(typo["id"], 1.29, "m", "typed 12.9 for 1.29")
    assert out["objective"] == pytest.approx((2.0 + 1.29) / 2) and out["n_measurements"] == 2
    [new] = out["stored"]
    assert new["supersedes_id"] == typo["id"] and new["source"] == "tape"
    # the next suggestion's model sees the corrected data
    model = api.model(exp["id"])
    assert model["incumbent_objective"] == pytest.approx(1.645)
    assert model["incumbent_trial_index"] == b["index"]
    # withdraw one of a's repeats: the objective is the other one
    out = api.withdraw_measurement(a["measurements"][0]["id"], "the cube bounced off the tape")
    assert out["objective"] == pytest.approx(1.2) and out["objective_sem"] is None
    err = error_of(api.withdraw_measurement, a["measurements"][0]["id"], "again")
    assert err.status == 409 and "already withdrawn" in err.detail
    # a bad correction is refused, nothing changed
    err = error_of(api.supersede_measurement, new["id"], -1.0, "m", "sign")
    assert err.status == 422 and "negative" in err.detail
    assert api.get_trial(b["id"])["objective"] == pytest.approx(1.645)
    # nothing deleted: every value is kept, the withdrawn ones say who, when and why
    reps = api.get_trial(b["id"])["measurements"]
    assert [r["value"] for r in reps] == [2.0, 12.9, 1.29]
    assert reps[1]["withdrawn_by"] == "operator" and reps[1]["withdrawn_reason"]
    assert reps[0]["withdrawn_at"] is None and reps[2]["withdrawn_at"] is None
    actions = [x["action"] for x in api.audit(exp["id"])]
    assert "measurement.supersede" in actions and "measurement.withdraw" in actions
    [suggested] = api.suggest(exp["id"])  # the optimiser runs on the corrected data
    assert suggested["status"] == "awaiting_confirmation"


def test_tracker_and_tape_are_not_averaged(hw_exp, api):
    exp = hw_exp(api)
    assert exp["objective_sources"] == ["tape", "imported"]
    [t] = api.suggest(exp["id"])
    api.preview_and_confirm(t)
    api.add_measurements(t["id"], tape(5.0, source="tracker"))
    tr = api.get_trial(t["id"])
    assert tr["status"] == "completed" and tr["objective"] is None  # awaits the tape
    api.add_measurements(t["id"], tape(1.0, 1.2))
    tr = api.get_trial(t["id"])
    assert tr["objective"] == pytest.approx(1.1) and tr["n_measurements"] == 2
    assert [m["source"] for m in tr["measurements"]] == ["tracker", "tape", "tape"]
    # an experiment that chose the tracker
    by_tracker = hw_exp(api, objective_sources=["tracker"])
    [t] = api.suggest(by_tracker["id"])
    api.preview_and_confirm(t)
    api.add_measurements(t["id"], tape(5.0, source="tracker") + tape(1.0))
    assert api.get_trial(t["id"])["objective"] == pytest.approx(5.0)
    # defaults: tracker for tip speed on hardware, the simulator for sim experiments
    tip = api.create_experiment(
        name="tip", task="tip_speed", levels=3, target="hardware", limits={"nominal_pa": 1e5}
    )
    assert tip["objective_sources"] == ["tracker", "imported"]
    sim = api.create_experiment(name="sim", task="tip_speed", levels=3, sim_preset="fast")
    [t] = api.suggest(sim["id"])
    done = api.run_trial(t["id"])
    assert api.get_trial(done["id"])["measurements"][0]["source"] == "sim"
    assert done["objective"] is not None
