"""An experiment's JSON bundle round-trips (issue 16, finding 7): export → import → export
gives the same record (trials, raw measurements with who and their corrections, previews,
confirmations, trajectories, audit log) but for ids, file paths and the import's own audit
row."""

from __future__ import annotations

import json

import pytest

from app.db.base import utcnow
from app.db.models import Preview
from app.service import bundle, runs, trials
from app.service import lifecycle as lc
from app.service.errors import InvalidInput
from app.service.measurements import add_measurements, supersede_measurement
from app.service.schemas import MeasurementsIn, SupersedeIn

from .conftest import OPERATOR


def _comparable(b: dict) -> dict:
    b = json.loads(json.dumps(b))
    b["experiment"].pop("id")
    for t in b["trials"]:
        t.pop("id"), t.pop("experiment_id")
    for name in ("measurements", "confirmations", "previews", "artifacts"):
        for r in b[name]:
            r.pop("id"), r.pop("trial_id")
            r.pop("path", None)
            r.pop("supersedes_id", None)
    b["audit"] = [
        {k: v for k, v in r.items() if k not in ("id", "experiment_id", "trial_id", "entity_id")}
        for r in b["audit"]
        if r["action"] != "experiment.import_bundle"
    ]
    return b


def test_export_import_export_round_trips(db, make_experiment, make_trial, tmp_path):
    art = tmp_path / "artifacts"
    exp_id = make_experiment(sim_preset="fast")
    ran = make_trial(exp_id, status=lc.QUEUED)
    runs.run_trial(db, ran, actor=OPERATOR, artifacts_dir=art)  # a trajectory, audit rows
    measured = make_trial(exp_id, status=lc.QUEUED, theta=[0.2] * 10)
    with db.write() as s:
        body = MeasurementsIn.model_validate(
            {
                "repeats": [
                    {"value": 1.5, "unit": "m/s", "note": "tape"},
                    {"value": 1.7, "unit": "m/s"},
                ]
            }
        )
        receipt = add_measurements(s, measured, body, idempotency_key="k1", actor=OPERATOR)
    with db.write() as s:
        fix = SupersedeIn(value=1.8, unit="m/s", reason="misread the tape")
        supersede_measurement(s, receipt.stored[1].id, fix, actor=OPERATOR)
        s.add(
            Preview(
                trial_id=measured,
                schedule_hash="ab" * 32,
                hold="zero",
                sim_preset="fast",
                job_id="j1",
                predicted_objective=1.6,
                previewed_by=OPERATOR.username,
                previewed_at=utcnow(),
            )
        )
    with db.write() as s:
        trials.fail(s, make_trial(exp_id, theta=[0.9] * 10), "valve stuck", actor=OPERATOR)
    with db.read() as s:
        first = bundle.export_bundle(s, exp_id, art)
    assert len(first["trials"]) == 3 and len(first["measurements"]) == 4
    assert len(first["previews"]) == 1
    assert first["artifacts"][0]["content_b64"] and first["audit"]
    text = json.dumps(first, allow_nan=False)  # strict JSON
    with db.write() as s:
        new_id = bundle.import_bundle(s, json.loads(text), art, actor=OPERATOR)
    assert new_id != exp_id
    with db.read() as s:
        again = bundle.export_bundle(s, new_id, art)
    assert _comparable(again) == _comparable(first)
    # the correction points at the repeat it corrects, among the imported ones
    ms = {m["id"]: m for m in again["measurements"]}
    [fixed] = [m for m in ms.values() if m["supersedes_id"] is not None]
    assert fixed["value"] == 1.8 and ms[fixed["supersedes_id"]]["withdrawn_reason"] == (
        "misread the tape"
    )
    assert again["previews"][0]["trial_id"] in {t["id"] for t in again["trials"]}
    assert again["audit"][-1]["action"] == "experiment.import_bundle"


def test_a_damaged_bundle_is_refused_and_nothing_stored(db, make_experiment, make_trial, tmp_path):
    art = tmp_path / "artifacts"
    exp_id = make_experiment(sim_preset="fast")
    runs.run_trial(db, make_trial(exp_id, status=lc.QUEUED), actor=OPERATOR, artifacts_dir=art)
    with db.read() as s:
        b = bundle.export_bundle(s, exp_id, art)
    b["artifacts"][0]["content_b64"] = "AAAA"
    with pytest.raises(InvalidInput, match="does not match its SHA-256"), db.write() as s:
        bundle.import_bundle(s, b, art, actor=OPERATOR)
    with db.read() as s:
        from app.db.models import Experiment

        assert s.query(Experiment).count() == 1
    with pytest.raises(InvalidInput, match="not a handful-experiment-bundle"), db.write() as s:
        bundle.import_bundle(s, {"format": "zip"}, art, actor=OPERATOR)
