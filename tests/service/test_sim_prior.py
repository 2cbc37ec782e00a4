"""The sim prior in the service: linking a hardware experiment to a sim experiment (accepted,
or refused naming each difference), its scored trials reaching the optimiser (the suggestion
basis says so), sim trials outside the hardware budget, and starting one."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import select

from app.db.models import AuditLog, Experiment, Trial
from app.service import data, sim_prior, trials
from app.service.errors import Conflict, InvalidInput
from app.service.experiments import create_experiment, read_experiment
from app.service.schemas import ExperimentCreate, ImportIn, SimPriorStartIn
from tests.service.conftest import OPERATOR

LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0}
#: a small acquisition search and GP fit: these tests check what the optimiser leaned on
QUICK = {"num_restarts": 2, "raw_samples": 64, "fit_maxiter": 20}
HW = {
    "target": "hardware",
    "levels": 3,
    "method": "bo-lei-default",
    "limits": LIMITS,
    "optimizer_settings": QUICK,
}


def _scored_sim(db, exp_id: int, n: int = 6, seed: int = 0) -> list[list[float]]:
    """``n`` scored sim trials (imported observations): θ and objective; the best last."""
    rng = np.random.default_rng(seed)
    thetas = rng.random((n, 10)).tolist()
    body = ImportIn.model_validate(
        {"observations": [{"theta": th, "objective": 1.0 + i} for i, th in enumerate(thetas)]}
    )
    with db.write() as s:
        data.import_observations(s, exp_id, body, actor=OPERATOR)
    return thetas


def test_linking_a_matching_sim_experiment_is_accepted_and_audited(db, make_experiment):
    sim = make_experiment(levels=3, sim_preset="fast", limits=LIMITS)
    hw = make_experiment(**HW)
    with db.write() as s:
        out = sim_prior.link(s, hw, sim, actor=OPERATOR)
    assert out.sim_prior_experiment_id == sim
    with db.read() as s:
        [row] = s.scalars(select(AuditLog).where(AuditLog.action == "experiment.sim_prior"))
        assert (row.before, row.after, row.actor) == (None, str(sim), "olivia")
        prior = sim_prior.read_sim_prior(s, hw)
        assert (prior.sim_experiment_id, prior.sim_preset, prior.twin_preset) == (
            sim,
            "fast",
            "fast",
        )
    # at creation too, and unlinking drops it
    with db.write() as s:
        made = create_experiment(
            s,
            ExperimentCreate(name="hw2", task="tip_speed", sim_prior_experiment_id=sim, **HW),
            actor=OPERATOR,
        )
        assert made.sim_prior_experiment_id == sim
        assert sim_prior.unlink(s, made.id, actor=OPERATOR).sim_prior_experiment_id is None


@pytest.mark.parametrize(
    ("sim_fields", "hw_fields", "words"),
    [
        ({"task": "hammer"}, {}, "the task differs (tip_speed here, hammer there)"),
        ({"levels": 5}, {}, "the pressure levels P differ (3 here, 5 there)"),
        ({"horizon": 8}, {}, "the control steps H differ (10 here, 8 there)"),
        ({"with_release": True}, {}, "the release step differs (not here, learned there)"),
        (
            {"command_hold": "linear"},
            {},
            "the command hold differs (zero (each row held) here, linear (ramped) there)",
        ),
        (
            {"limits": None},
            {},
            "the pressure limits differ (nominal 100 kPa ± 30 kPa, source 205 kPa here, the "
            "simulator's full range, 0 to 275.8 kPa there: the same θ would be other pressures)",
        ),
        (
            {"limits": {**LIMITS, "max_step_pa": 20_000.0}},
            {},
            "(nominal 100 kPa ± 30 kPa, source 205 kPa here, nominal 100 kPa ± 20 kPa",
        ),
        ({"target": "hardware"}, {}, "runs on hardware, not in simulation"),
        ({}, {"target": "sim"}, "runs in simulation: only a hardware experiment has one"),
    ],
)
def test_linking_what_differs_is_refused_in_words(
    db, make_experiment, sim_fields, hw_fields, words
):
    sim = make_experiment(**{"levels": 3, "limits": LIMITS, **sim_fields})
    hw = make_experiment(**{**HW, **hw_fields})
    with pytest.raises(InvalidInput, match="cannot be the sim prior") as err, db.write() as s:
        sim_prior.link(s, hw, sim, actor=OPERATOR)
    assert words in str(err.value)
    assert str(err.value).startswith("sim_prior_experiment_id: ")  # the form places it
    with db.read() as s:
        assert s.get(Experiment, hw).sim_prior_experiment_id is None
    # refused at creation: nothing stored
    with db.read() as s:
        before = len(s.scalars(select(Experiment)).all())
    spec = {"name": "hw", "task": "tip_speed", **HW, **hw_fields, "sim_prior_experiment_id": sim}
    with pytest.raises(InvalidInput, match="cannot be the sim prior"), db.write() as s:
        create_experiment(s, ExperimentCreate(**spec), actor=OPERATOR)
    with db.read() as s:
        assert len(s.scalars(select(Experiment)).all()) == before


def test_every_difference_is_named_at_once(db, make_experiment):
    sim = make_experiment(task="hammer", levels=5, command_hold="linear")
    hw = make_experiment(**HW)
    with pytest.raises(InvalidInput) as err, db.write() as s:
        sim_prior.link(s, hw, sim, actor=OPERATOR)
    text = str(err.value)
    assert "task differs" in text and "levels P differ" in text and "command hold" in text
    with pytest.raises(InvalidInput, match="there is no experiment 999"), db.write() as s:
        sim_prior.link(s, hw, 999, actor=OPERATOR)


def test_the_prior_reaches_the_optimiser_and_each_trial_says_what_it_leaned_on(db, make_experiment):
    sim = make_experiment(levels=3, limits=LIMITS)
    hw = make_experiment(sim_prior_experiment_id=sim, **HW)
    thetas = _scored_sim(db, sim, n=6)
    actor = OPERATOR
    # multitask (the BO default): the design is the prior's best θ, best first
    first, second = trials.suggest(db, hw, 2, actor=actor)
    assert np.allclose(first.theta, thetas[-1]) and np.allclose(second.theta, thetas[-2])
    basis = first.suggestion_basis
    assert basis["mode"] == "multitask" and basis["n_prior"] == 6 and basis["step"] == "prior"
    assert basis["sim_experiment_id"] == sim and basis["n_own"] == 0
    # two hardware results later the multitask GP over (θ, source) makes the suggestion
    with db.write() as s:
        for t, value in ((first, 1.2), (second, 0.9)):
            row = s.get(Trial, t.id)
            row.status, row.objective, row.n_measurements = "completed", value, 1
    [third] = trials.suggest(db, hw, 1, actor=actor)
    b = third.suggestion_basis
    assert (b["mode"], b["step"], b["n_prior"], b["n_own"]) == ("multitask", "model", 6, 2)
    assert b["task_correlation"] is not None and -1.0 <= b["task_correlation"] <= 1.0
    assert third.predicted_mean is not None  # the GP's prediction, shown beside the twin's
    # without the link the same experiment learns from hardware alone
    with db.write() as s:
        sim_prior.unlink(s, hw, actor=actor)
    [fourth] = trials.suggest(db, hw, 1, actor=actor)
    assert fourth.suggestion_basis["mode"] is None and fourth.suggestion_basis["n_prior"] == 0


def test_sim_trials_never_count_against_the_hardware_budget(db, make_experiment):
    sim = make_experiment(levels=3, limits=LIMITS)
    hw = make_experiment(
        budget=2,
        sim_prior_experiment_id=sim,
        **{**HW, "method": "random", "optimizer_settings": {}},
    )
    _scored_sim(db, sim, n=8)
    made = trials.suggest(db, hw, 2, actor=OPERATOR)
    assert [t.suggestion_basis["step"] for t in made] == ["prior", "prior"]  # warmstart
    with db.read() as s:
        exp = read_experiment(s, hw)
        assert (exp.n_budget_used, exp.budget_reached) == (2, True)
        assert sim_prior.read_sim_prior(s, hw).n_scored == 8
    with pytest.raises(Conflict, match="budget of 2 trials reached"):
        trials.suggest(db, hw, 1, actor=OPERATOR)
    # the sim side goes on regardless
    assert len(trials.suggest(db, sim, 3, actor=OPERATOR)) == 3


def test_start_one_creates_a_linked_sim_twin_experiment_with_queued_trials(db, make_experiment):
    hw = make_experiment(task="throw", command_hold="linear", **HW)

    def suggest(sim_id: int, n: int):
        return trials.suggest(db, sim_id, n, actor=OPERATOR)

    out = sim_prior.start(db, hw, SimPriorStartIn(n_trials=4), actor=OPERATOR, suggest=suggest)
    sim = out.sim_experiment
    assert out.experiment.sim_prior_experiment_id == sim.id
    assert (sim.target, sim.task, sim.levels, sim.horizon, sim.with_release) == (
        "sim",
        "throw",
        3,
        10,
        True,
    )
    assert (sim.command_hold, sim.sim_preset, sim.method) == ("linear", "fast", "bo-lei-default")
    assert sim.limits == out.experiment.limits  # the same θ is the same pressures
    assert [t.status for t in out.queued] == ["queued"] * 4  # for the sim workers
    with pytest.raises(Conflict, match="already has sim experiment"):
        sim_prior.start(db, hw, SimPriorStartIn(n_trials=1), actor=OPERATOR, suggest=suggest)
    with pytest.raises(InvalidInput, match="only a hardware experiment"):
        sim_prior.start(db, sim.id, SimPriorStartIn(), actor=OPERATOR, suggest=suggest)


def test_the_default_preset_is_the_paper_matching_one():
    from app.bench import PAPER_PRESET

    assert sim_prior.DEFAULT_PRESET == PAPER_PRESET
