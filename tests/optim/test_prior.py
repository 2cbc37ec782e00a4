"""A sim prior for the optimisers: validated data, a multitask GP that learns from it, a warm
start of the initial design, what a suggestion leaned on, and weighing data by age."""

from __future__ import annotations

import numpy as np
import pytest

from app.optim import (
    METHODS,
    BayesOpt,
    OptimizerSpec,
    PriorData,
    SettingsError,
    build_optimizer,
    make_optimizer,
)
from app.optim.bo import age_noise

FAST = {"num_restarts": 2, "raw_samples": 64, "fit_maxiter": 60}
DIM = 3


def target(x: np.ndarray) -> np.ndarray:
    """The 'hardware' objective: a bump near 0.3 plus a slope."""
    x = np.atleast_2d(x)
    return np.exp(-6.0 * np.sum((x - 0.3) ** 2, axis=1)) + 0.3 * x[:, 0]


def sim(x: np.ndarray) -> np.ndarray:
    """The 'simulator': the same shape, shifted a little, offset and scaled (a reality gap)."""
    x = np.atleast_2d(x)
    return 2.0 * (np.exp(-6.0 * np.sum((x - 0.36) ** 2, axis=1)) + 0.3 * x[:, 0]) + 0.5


def prior_data(n: int = 40, seed: int = 0, f=sim) -> PriorData:
    x = np.random.default_rng(seed).random((n, DIM))
    return PriorData(x, f(x), source="sim test")


@pytest.mark.slow
def test_the_multitask_gp_predicts_a_held_out_target_better_with_a_correlated_prior():
    rng = np.random.default_rng(1)
    own = rng.random((6, DIM))
    held_out = rng.random((300, DIM))
    truth = target(held_out)

    def rmse(opt: BayesOpt) -> float:
        opt.observe(own, target(own))
        return float(np.sqrt(np.mean((opt.predict(held_out)[0] - truth) ** 2)))

    plain = rmse(make_optimizer("bo-lei-default", DIM, seed=0, **FAST))
    multi = make_optimizer("bo-lei-default", DIM, seed=0, prior=prior_data(), **FAST)
    with_prior = rmse(multi)
    # an unrelated prior (another function) teaches it nothing useful
    other = prior_data(f=lambda x: np.sin(9.0 * x[:, 2]) * np.cos(7.0 * x[:, 1]))
    lost = make_optimizer("bo-lei-default", DIM, seed=0, prior=other, **FAST)
    unrelated = rmse(lost)
    assert with_prior < 0.7 * plain, (with_prior, plain)
    assert unrelated > 1.5 * with_prior, (unrelated, with_prior)
    multi.suggest(1)
    lost.suggest(1)
    basis = multi.suggestion_basis()
    assert basis["mode"] == "multitask" and basis["steps"] == ["model"]
    assert (basis["n_prior"], basis["n_own"]) == (40, 6)
    # it learned that the sim and the target go together, and the unrelated data do not
    assert basis["task_correlation"] > lost.suggestion_basis()["task_correlation"] + 0.2
    assert multi.lengthscales().shape == (DIM,)


@pytest.mark.parametrize("method", ["bo-lei-default", "random", "cem", "cmaes", "optuna-tpe"])
def test_warmstart_first_suggestions_are_the_priors_best(method):
    prior = prior_data()
    settings = {**FAST} if method.startswith("bo-") else {}
    opt = make_optimizer(method, DIM, seed=2, prior=prior, prior_mode="warmstart", **settings)
    best = prior.best(2)
    np.testing.assert_array_equal(best[0], prior.theta[np.argmax(prior.objective)])
    first = opt.suggest(1)
    assert opt.suggestion_basis()["steps"] == ["prior"]
    np.testing.assert_array_equal(first[0], best[0])
    # pending: the next one is the second best, then the method's own design goes on
    nxt = opt.suggest(2, pending=first)
    np.testing.assert_array_equal(nxt[0], best[1])
    assert opt.suggestion_basis()["steps"][0] == "prior"
    assert opt.suggestion_basis()["steps"][1] in ("design", "model")
    assert not np.allclose(nxt[1], best[0]) and not np.allclose(nxt[1], best[1])
    opt.observe(first, target(first))
    opt.observe(nxt[:1], target(nxt[:1]))
    after = opt.suggest(1)
    assert not any(np.allclose(after[0], b) for b in best)
    assert opt.suggestion_basis()["n_prior"] == 0  # nothing of the prior in this one
    # without a prior the same method starts elsewhere
    bare = make_optimizer(method, DIM, seed=2, **settings)
    assert not np.allclose(bare.suggest(1)[0], best[0])
    assert bare.suggestion_basis()["mode"] is None


@pytest.mark.slow
def test_multitask_starts_from_the_priors_best_then_asks_its_model():
    prior = prior_data()
    opt = make_optimizer("bo-lei-default", DIM, seed=0, prior=prior, n_initial=12, **FAST)
    assert opt.n_initial == 2  # the prior's best replace the design
    steps = []
    for _ in range(4):
        x = opt.suggest(1)
        steps.append(opt.suggestion_basis()["steps"][0])
        opt.observe(x, target(x))
    assert steps == ["prior", "prior", "model", "model"]
    np.testing.assert_array_equal(opt.train_data()[0][:2], prior.best(2))


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: PriorData(np.random.rand(4, DIM), np.ones(3)), "objective must have shape (4,)"),
        (lambda: PriorData(np.random.rand(DIM), np.ones(DIM)), "shape (N, D)"),
        (lambda: PriorData([[0.1, np.nan, 0.2]], [1.0]), "θ of trial 0 is not finite"),
        (lambda: PriorData([[0.1, 0.5, 0.2]], [np.nan]), "objective of trial 0 is not finite"),
        (lambda: PriorData([[0.1, 1.5, 0.2]], [1.0]), "θ[0][1] = 1.5 is outside [0, 1]"),
        (lambda: PriorData([["a", 1, 2]], [1.0]), "must be numbers"),
        (
            lambda: make_optimizer("bo-lei", 4, seed=0, prior=prior_data()),
            "its θ have 3 dimensions but this optimiser's have 4",
        ),
        (
            lambda: make_optimizer("cem", DIM, seed=0, prior=prior_data(), prior_mode="multitask"),
            "prior_mode 'multitask' needs a BO method",
        ),
        (lambda: make_optimizer("cem", DIM, seed=0, prior_mode="multitask"), "needs a BO method"),
        (lambda: make_optimizer("bo-lei", DIM, seed=0, prior_mode="both"), "prior_mode must be"),
        (lambda: make_optimizer("random", DIM, seed=0, prior_top_k=-1), "prior_top_k must be"),
        (lambda: make_optimizer("bo-lei", DIM, seed=0, prior=[[0.1]]), "must be a PriorData"),
        (
            lambda: make_optimizer("bo-lei", DIM, seed=0, age_halflife_trials=0),
            "age_halflife_trials must be a number of trials > 0",
        ),
    ],
)
def test_bad_priors_and_prior_settings_are_refused_with_what_is_wrong(make, message):
    with pytest.raises(SettingsError) as err:
        make()
    assert message in str(err.value)


def test_every_method_takes_a_prior_through_the_spec_and_the_defaults_fit_it():
    prior = prior_data(n=5)
    for method in METHODS:
        spec = OptimizerSpec(method, levels=3, horizon=3, with_release=False, seed=0, prior=prior)
        opt = build_optimizer(spec)
        assert opt.prior_mode == ("multitask" if method.startswith("bo-") else "warmstart")
        np.testing.assert_array_equal(opt.suggest(1)[0], prior.best(1)[0])
    # prior_mode alone (the experiment's setting before it is linked) is accepted
    spec = OptimizerSpec("cem", 3, 3, False, 0, settings={"prior_mode": "warmstart"})
    assert build_optimizer(spec).prior is None
    assert spec == OptimizerSpec("cem", 3, 3, False, 0, settings={"prior_mode": "warmstart"})
    assert PriorData(prior.theta, prior.objective) == prior  # equal data, equal priors


@pytest.mark.parametrize(
    "settings",
    [
        pytest.param({"prior_mode": "multitask"}, marks=pytest.mark.slow),
        {"prior_mode": "warmstart", "age_halflife_trials": 3.0},
        pytest.param(
            {"prior_mode": "multitask", "age_halflife_trials": 3.0}, marks=pytest.mark.slow
        ),
    ],
)
def test_the_optimiser_rebuilt_from_observations_equals_the_live_one(settings):
    prior = prior_data(n=12)
    spec = OptimizerSpec(
        "bo-lei-default",
        levels=3,
        horizon=DIM,
        with_release=False,
        seed=5,
        settings={**FAST, **settings},
        n_initial=3,
        prior=prior,
    )
    opt = build_optimizer(spec)
    for _ in range(4):
        x = opt.suggest(1)
        opt.observe(x, target(x))
    rebuilt = build_optimizer(spec)
    rebuilt.observe_many(opt.observations)
    np.testing.assert_array_equal(opt.suggest(1), rebuilt.suggest(1))
    assert opt.suggestion_basis() == rebuilt.suggestion_basis()
    pending = np.array([[0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(
        opt.suggest(2, pending=pending), rebuilt.suggest(2, pending=pending)
    )


def test_weighing_by_age_follows_a_drifting_robot():
    np.testing.assert_allclose(age_noise(3, 1.0), [3.0, 1.0, 0.0])
    np.testing.assert_allclose(age_noise(2, 2.0), [np.sqrt(2.0) - 1.0, 0.0])
    # the same θ region measured 10 times before a drift (value 0) and 4 times after (value 1)
    rng = np.random.default_rng(0)
    x = 0.5 + 0.05 * rng.standard_normal((14, DIM))
    y = np.r_[np.zeros(10), np.ones(4)] + 0.01 * rng.standard_normal(14)
    centre = np.full((1, DIM), 0.5)
    preds = {}
    for h in (None, 2.0):
        opt = make_optimizer("bo-lei", DIM, seed=0, age_halflife_trials=h, **FAST)
        opt.observe(x, y)
        preds[h] = float(opt.predict(centre)[0][0])
    assert preds[None] < 0.5 < preds[2.0], preds  # without ageing the old majority wins
