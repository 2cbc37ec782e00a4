"""Weighing data by age: the experiment's ``age_halflife_trials`` reaches the BO optimiser the
service builds (and its suggestions), can be changed and switched off, and is audited."""

from __future__ import annotations

import numpy as np

from app.service import experiments, trials
from app.service.data import import_observations
from app.service.schemas import ExperimentPatch, ImportIn
from tests.conftest import OPERATOR


def test_the_half_life_reaches_the_optimiser_and_can_be_changed(db, make_experiment):
    exp_id = make_experiment(method="bo-lei-default", n_initial=2, age_halflife_trials=4.0)
    rng = np.random.default_rng(0)
    with db.write() as s:
        body = {"observations": [{"theta": rng.random(10).tolist(), "objective": float(v)}
                                 for v in (1.0, 1.4, 0.8, 1.1)]}  # fmt: skip
        import_observations(s, exp_id, ImportIn(**body), actor=OPERATOR)
    with db.read() as s:
        exp = experiments.get_experiment(s, exp_id)
        inputs = trials.optimizer_inputs(s, exp)
        assert experiments.read_experiment(s, exp_id).age_halflife_trials == 4.0
    assert inputs.spec.kwargs()["age_halflife_trials"] == 4.0
    opt = trials.rebuild_optimizer(inputs)
    assert opt.settings.age_halflife_trials == 4.0  # type: ignore[attr-defined]
    [made] = trials.suggest(db, exp_id, 1, actor=OPERATOR)  # a GP fitted with aged data
    assert made.predicted_mean is not None and np.isfinite(made.predicted_std)

    with db.write() as s:
        out = experiments.patch_experiment(
            s, exp_id, ExperimentPatch(age_halflife_trials=None), actor=OPERATOR
        )
        assert out.age_halflife_trials is None
        exp = experiments.get_experiment(s, exp_id)
        assert "age_halflife_trials" not in trials.optimizer_inputs(s, exp).spec.kwargs()
    with db.read() as s:
        [entry] = [
            a
            for a in experiments.audit_log(s, exp_id)
            if a.action == "experiment.age_halflife_trials"
        ]
        assert (entry.before, entry.after) == ("4.0", None)


def test_a_bundle_keeps_the_drift_check_pointing_at_its_own_trial(db, make_experiment, tmp_path):
    from app.service import bundle, drift
    from app.service.schemas import ReferenceIn

    exp_id = make_experiment(target="hardware")
    with db.write() as s:
        first = trials.attach(s, exp_id, [0.2] * 10, note="", actor=OPERATOR)
        drift.set_reference(
            s,
            exp_id,
            ReferenceIn(every=4, theta_from="trial", trial_index=1, tolerance=0.05),
            actor=OPERATOR,
        )
        exported = bundle.export_bundle(s, exp_id, tmp_path)
    with db.write() as s:
        new_id = bundle.import_bundle(s, exported, tmp_path, actor=OPERATOR)
    with db.read() as s:
        view = drift.drift_view(s, new_id)
        new_first = trials.list_trials(s, new_id)[0]
    assert new_first.id != first.id
    assert view.reference is not None and view.reference.trial_id == new_first.id
    assert (view.reference_trial_index, view.reference.every) == (1, 4)
    assert view.reference.tolerance == 0.05 and view.reference.theta == first.theta
