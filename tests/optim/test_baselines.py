"""CEM, random search, CMA-ES and the Optuna samplers behind the ask/tell interface."""

from __future__ import annotations

import numpy as np
import pytest

from app.optim import CEM, make_optimizer


def bumpy(theta: np.ndarray) -> float:
    th = np.asarray(theta)
    return float(-np.sum((th - 0.7) ** 2) + 0.05 * np.cos(9.0 * th).sum())


def run(method: str, dim: int, n: int, seed: int = 0, **settings):
    opt = make_optimizer(method, dim, seed=seed, **settings)
    for _ in range(n):
        x = opt.suggest(1)[0]
        opt.observe(x, bumpy(x))
    return opt


def test_cem_elite_update_takes_mean_and_std_of_the_top_fifth():
    cem = CEM(3, seed=0, population=10, elite_frac=0.2)
    assert cem.n_elite == 2
    theta = np.random.default_rng(0).random((10, 3))
    values = np.arange(10.0)
    values[[3, 7]] = [100.0, 50.0]  # the elite: rows 3 and 7
    mean, std = cem.elite_update(theta, values)
    np.testing.assert_allclose(mean, theta[[3, 7]].mean(axis=0))
    np.testing.assert_allclose(std, theta[[3, 7]].std(axis=0))


def test_cem_starts_from_the_mean_of_d_plus_1_samples_with_a_box_wide_spread():
    dim = 4
    cem = make_optimizer("cem", dim, seed=3)
    assert cem.population == 50 and cem.n_elite == 10 and cem.n_initial == dim + 1
    first = cem.suggest(dim + 1)
    cem.observe(first, [bumpy(x) for x in first])
    mean, std, gen = cem.distribution()
    np.testing.assert_allclose(mean, first.mean(axis=0))
    np.testing.assert_allclose(std, 1.0)
    assert gen == 0
    pop = cem.suggest(50)
    assert (pop >= 0).all() and (pop <= 1).all()
    assert ((pop == 0) | (pop == 1)).mean() > 0.2  # clipped samples land on the box's faces
    values = np.array([bumpy(x) for x in pop])
    cem.observe(pop, values)
    mean, std, gen = cem.distribution()
    elite = pop[np.argsort(-values)[:10]]
    assert gen == 1
    np.testing.assert_allclose(mean, elite.mean(axis=0))
    np.testing.assert_allclose(std, elite.std(axis=0))


def test_the_papers_cem_spreads_its_first_generation_like_the_uniform_box():
    """σ₀ = 1/√12 (the paper's CEM) keeps most samples inside the box; σ₀ = 1 (the default)
    puts most coordinates on its faces (bang-bang schedules)."""
    from app.optim.baselines import PAPER_CEM_INIT_STD

    faces = {}
    for std in (PAPER_CEM_INIT_STD, 1.0):
        cem = make_optimizer("cem", 11, seed=5, init_std=std)
        first = cem.suggest(12)
        cem.observe(first, [bumpy(x) for x in first])
        pop = cem.suggest(50)
        faces[std] = ((pop == 0) | (pop == 1)).mean()
        if std == PAPER_CEM_INIT_STD:
            assert 0.2 < pop.std() < 0.38  # about a uniform's 0.29 over the box
    assert faces[PAPER_CEM_INIT_STD] < 0.15 and faces[1.0] > 0.5


def test_random_search_is_uniform_and_reproducible():
    a = make_optimizer("random", 5, seed=1).suggest(200)
    b = make_optimizer("random", 5, seed=1).suggest(200)
    np.testing.assert_array_equal(a, b)
    assert abs(a.mean() - 0.5) < 0.05 and a.min() >= 0 and a.max() <= 1
    assert not np.array_equal(a, make_optimizer("random", 5, seed=2).suggest(200))


@pytest.mark.parametrize(
    ("method", "n"), [("cem", 60), ("random", 10), ("cmaes", 25), ("optuna-tpe", 15)]
)
def test_rebuilding_from_observations_gives_the_live_suggestion(method, n):
    live = run(method, 4, n, seed=7)
    rebuilt = make_optimizer(method, 4, seed=7)
    rebuilt.observe_many(live.observations)
    np.testing.assert_array_equal(live.suggest(3), rebuilt.suggest(3))
    pending = live.suggest(2)
    np.testing.assert_array_equal(
        live.suggest(1, pending=pending), rebuilt.suggest(1, pending=pending)
    )


def test_optuna_gp_rebuilds_identically_and_stays_in_the_box():
    live = run("optuna-gp", 3, 12, seed=4)
    rebuilt = make_optimizer("optuna-gp", 3, seed=4)
    rebuilt.observe_many(live.observations)
    x = live.suggest(1)
    np.testing.assert_array_equal(x, rebuilt.suggest(1))
    assert x.shape == (1, 3) and (x >= 0).all() and (x <= 1).all()


@pytest.mark.parametrize("method", ["cem", "random", "cmaes"])
def test_a_pending_point_holds_its_place_in_the_sequence(method):
    """With one point pending, the next suggestion is the second of a batch of two."""
    opt = run(method, 4, 20, seed=2)
    batch = opt.suggest(2)
    first = opt.suggest(1)
    np.testing.assert_array_equal(first, batch[:1])
    np.testing.assert_array_equal(opt.suggest(1, pending=first), batch[1:])
    assert np.abs(batch[0] - batch[1]).max() > 1e-6


def test_peers_improve_on_a_smooth_function():
    for method in ("cmaes", "optuna-tpe", "cem"):
        opt = run(method, 3, 120, seed=0)
        _, y, _ = opt.train_data()
        assert y[-30:].mean() > y[:20].mean(), method


@pytest.mark.parametrize(
    ("method", "settings", "match"),
    [
        ("cem", {"population": 1}, "population"),
        ("cem", {"elite_frac": 0.0}, "elite_frac"),
        ("cmaes", {"sigma0": 0}, "sigma0"),
        ("optuna-tpe", {"bogus": 1}, "bogus"),
        ("random", {"population": 0}, "population"),
    ],
)
def test_bad_settings_raise_value_error(method, settings, match):
    with pytest.raises(ValueError, match=match):
        make_optimizer(method, 3, seed=0, **settings)
