"""BayesOpt behind the ask/tell interface: model presets, acquisitions, purity, SEM, pending."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from botorch.acquisition.analytic import UpperConfidenceBound
from botorch.test_functions import Hartmann
from gpytorch.kernels import MaternKernel, ScaleKernel
from gpytorch.likelihoods import FixedNoiseGaussianLikelihood

from app.optim import METHODS, BayesOpt, Observation, SettingsError, make_optimizer
from app.policy import Policy

FAST = {"num_restarts": 2, "raw_samples": 64, "fit_maxiter": 50}


def bumpy(theta: np.ndarray) -> float:
    """A cheap smooth test function on [0,1]^D with its maximum near θ = 0.3."""
    th = np.asarray(theta)
    return float(np.exp(-8.0 * np.sum((th - 0.3) ** 2)) + 0.1 * np.sin(5.0 * th.sum()))


def filled(method: str, dim: int, n: int, seed: int = 0, **settings) -> BayesOpt:
    """An optimiser holding n observations of ``bumpy`` at random points (no GP fits yet)."""
    opt = make_optimizer(method, dim, seed=seed, **settings)
    x = np.random.default_rng(seed).random((n, dim))
    opt.observe(x, [bumpy(v) for v in x])
    return opt


def live(method: str, dim: int, n: int, seed: int = 0, **settings) -> BayesOpt:
    """An optimiser that suggested and observed n points itself."""
    opt = make_optimizer(method, dim, seed=seed, **settings)
    for _ in range(n):
        x = opt.suggest(1)[0]
        opt.observe(x, bumpy(x))
    return opt


@pytest.mark.slow
def test_bo_beats_random_on_hartmann6_within_30_evaluations():
    f = Hartmann(dim=6, negate=True)  # maximum 3.32237
    best = {"bo-lei": [], "random": []}
    for seed in range(3):
        for method in best:
            # warm GP fits (the paper grid's BO): half the cost of a full refit per trial
            fast = {"num_restarts": 2, "raw_samples": 64, "fit_mode": "warm"}
            opt = make_optimizer(method, 6, seed=seed, **(fast if method == "bo-lei" else {}))
            ys = []
            for _ in range(30):
                x = opt.suggest(1)[0]
                y = float(f(torch.as_tensor(x)))
                opt.observe(x, y)
                ys.append(y)
            best[method].append(max(ys))
    bo, rnd = np.array(best["bo-lei"]), np.array(best["random"])
    assert (bo > rnd).all(), best
    assert bo.mean() > rnd.mean() + 0.5, best


def test_initial_design_is_d_plus_1_sobol_points_then_the_gp():
    opt = make_optimizer("bo-lei", 3, seed=5, **FAST)
    xs = []
    for _ in range(4):
        x = opt.suggest(1)[0]
        xs.append(x)
        opt.observe(x, bumpy(x))
    sobol = torch.quasirandom.SobolEngine(3, scramble=True, seed=5).draw(4, dtype=torch.float64)
    np.testing.assert_array_equal(np.array(xs), sobol.numpy())
    assert opt._model is None  # no GP was needed for the Sobol phase
    opt.suggest(1)
    assert opt._model is not None and opt._model_n == 4


def test_ucb_uses_beta_equal_kappa_so_value_is_mean_plus_sqrt_kappa_sigma():
    opt = filled("bo-ucb", 2, 8, kappa=0.9, **FAST)
    acq = opt._acquisition(opt.model(), None, 1, seed=0)
    assert isinstance(acq, UpperConfidenceBound)
    assert float(acq.beta) == pytest.approx(0.9)
    x = np.array([[0.2, 0.7], [0.9, 0.1]])
    mean, std = opt.predict(x)
    with torch.no_grad():
        ucb = acq(torch.as_tensor(x).unsqueeze(-2)).numpy()
    np.testing.assert_allclose(ucb, mean + math.sqrt(0.9) * std, rtol=1e-6)


@pytest.mark.parametrize("method", ["bo-lei", "bo-ucb", "bo-turbo"])
def test_rebuilding_from_observations_gives_the_live_suggestion(method):
    opt = live(method, 3, 6, seed=3, n_initial=5, **FAST)
    rebuilt = make_optimizer(method, 3, seed=3, n_initial=5, **FAST)
    rebuilt.observe_many(opt.observations)
    np.testing.assert_array_equal(opt.suggest(1), rebuilt.suggest(1))
    pending = np.array([[0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(
        opt.suggest(2, pending=pending), rebuilt.suggest(2, pending=pending)
    )


def test_distinct_never_suggests_a_schedule_already_run_or_pending():
    # |θ − ½| summed rewards the box's corners; at P = 2, H = 4 the corners of θ are schedules
    # a plain θ-space GP keeps coming back to (θ 0.001 and 0.002 decode to the same action).
    policy = Policy(levels=2, horizon=4)

    def keys_of(theta: np.ndarray) -> list[tuple[int, ...]]:
        return [tuple(row) for row in policy.grid_from_theta(theta).tolist()]

    f = lambda th: float(np.abs(th - 0.5).sum())  # noqa: E731
    settings = {"levels": 2, "horizon": 4, "n_initial": 4, **FAST}
    opt = make_optimizer("bo-lei-distinct", 4, seed=0, **settings)
    pending = None
    for _ in range(14):
        x = opt.suggest(2, pending=pending) if pending is not None else opt.suggest(1)
        keys = keys_of(x)
        assert len(set(keys)) == len(keys)
        assert not set(keys) & set(keys_of(opt.train_data()[0]))
        if pending is not None:
            assert not set(keys) & set(keys_of(pending))
        opt.observe(x[0], f(x[0]))
        pending = x[1:] if len(x) > 1 else np.array([[0.999, 0.999, 0.001, 0.5]])
    assert len(set(keys_of(opt.train_data()[0]))) == opt.n_observed == 14
    rebuilt = make_optimizer("bo-lei-distinct", 4, seed=0, **settings)
    rebuilt.observe_many(opt.observations)
    np.testing.assert_array_equal(opt.suggest(1), rebuilt.suggest(1))


def test_trust_region_grows_on_successes_shrinks_on_failures_and_restarts():
    from app.optim.bo import TR_LENGTH_INIT, TR_LENGTH_MAX, trust_region_state

    init = [1.0, 2.0]  # n_initial = 2: best 2.0
    assert trust_region_state(np.array(init), 2, 6).length == TR_LENGTH_INIT
    up3 = trust_region_state(np.array([*init, 3.0, 4.0, 5.0]), 2, 6)
    assert (up3.length, up3.successes) == (2 * TR_LENGTH_INIT, 0)
    assert trust_region_state(np.array([*init, 3, 4, 5, 6, 7, 8]), 2, 6).length == TR_LENGTH_MAX
    # a near-tie (within 1e-3 of the best) is a failure; D = 6 failures in a row halve it
    flat = trust_region_state(np.array([*init, 2.0001, 0, 0, 0, 0, 0]), 2, 6)
    assert (flat.length, flat.failures) == (TR_LENGTH_INIT / 2, 0)
    five = trust_region_state(np.array([*init, 0, 0, 0, 0, 0]), 2, 6)
    assert (five.length, five.failures) == (TR_LENGTH_INIT, 5)
    # a success resets the failure run
    mixed = trust_region_state(np.array([*init, 0, 0, 0, 0, 0, 9.0, 0]), 2, 6)
    assert (mixed.length, mixed.failures, mixed.successes) == (TR_LENGTH_INIT, 1, 0)
    # 7 halvings go below 0.5**7: the region restarts at its initial length
    collapsed = trust_region_state(np.array(init + [0.0] * 6 * 7), 2, 6)
    assert collapsed.length == TR_LENGTH_INIT
    assert trust_region_state(np.array(init + [0.0] * 6 * 6), 2, 6).length == TR_LENGTH_INIT / 64


def test_turbo_searches_a_box_around_the_best_observation():
    opt = filled("bo-turbo", 3, 12, seed=2, n_initial=4, **FAST)
    x, y, _ = opt.train_data()
    lo, hi = opt.search_bounds().numpy()
    best = x[int(np.argmax(y))]
    assert ((lo <= best) & (best <= hi)).all() and (lo >= 0).all() and (hi <= 1).all()
    assert ((hi - lo) < 1.0).any()  # narrower than the box in some dimension
    out = opt.suggest(1)[0]
    assert ((lo - 1e-9 <= out) & (out <= hi + 1e-9)).all()
    plain = filled("bo-lei-default", 3, 12, seed=2, n_initial=4, **FAST)
    np.testing.assert_array_equal(plain.search_bounds().numpy(), [[0, 0, 0], [1, 1, 1]])


def test_a_pending_point_is_not_suggested_again():
    # Sobol phase: the next design point, not the pending one.
    opt = make_optimizer("bo-lei", 3, seed=1, **FAST)
    first = opt.suggest(1)
    second = opt.suggest(1, pending=first)
    assert np.abs(first - second).max() > 1e-3
    # An abandoned design trial: of the pair (a, b), only b is pending; b is not given again.
    a_b = opt.suggest(2)
    again = opt.suggest(1, pending=a_b[1:])
    assert np.abs(again - a_b[1]).max() > 1e-3
    np.testing.assert_array_equal(again, opt.suggest(1, pending=a_b[1:]))  # still deterministic
    # GP phase: qLogNEI with the pending point fantasised.
    opt = filled("bo-lei", 3, 8, seed=1, **FAST)
    x1 = opt.suggest(1)
    x2 = opt.suggest(1, pending=x1)
    assert np.linalg.norm(x1 - x2) > 0.05
    batch = opt.suggest(3, pending=x1)
    assert np.linalg.norm(batch - x1, axis=1).min() > 1e-3
    assert len({tuple(np.round(b, 6)) for b in batch}) == 3


def test_sem_reaches_the_gp_as_a_fixed_noise_level():
    opt = make_optimizer("bo-lei", 2, seed=0, **FAST)
    rng = np.random.default_rng(0)
    x = rng.random((6, 2))
    y = np.array([bumpy(v) for v in x])
    sem = np.array([0.01, 0.02, 0.05, 0.1, 0.2, 0.3])
    opt.observe(x, y, sem=sem)
    model = opt.model()
    assert isinstance(model.likelihood, FixedNoiseGaussianLikelihood)
    stdv = float(model.outcome_transform.stdvs.squeeze())
    noise = model.likelihood.noise.detach().squeeze().numpy() * stdv**2
    np.testing.assert_allclose(noise, sem**2, rtol=1e-6)
    # With SEMs the suggestion uses the noisy acquisition and is still in the box.
    out = opt.suggest(1)
    assert out.shape == (1, 2) and (out >= 0).all() and (out <= 1).all()


def test_paper_preset_is_matern52_with_the_older_gamma_priors():
    opt = filled("bo-lei", 4, 6, **FAST)
    covar = opt.model().covar_module
    assert isinstance(covar, ScaleKernel) and isinstance(covar.base_kernel, MaternKernel)
    assert covar.base_kernel.nu == 2.5 and covar.base_kernel.ard_num_dims == 4
    ls_prior = covar.base_kernel.lengthscale_prior
    assert (float(ls_prior.concentration), float(ls_prior.rate)) == pytest.approx((3.0, 6.0))
    os_prior = covar.outputscale_prior
    assert (float(os_prior.concentration), float(os_prior.rate)) == pytest.approx((2.0, 0.15))
    noise_prior = opt.model().likelihood.noise_covar.noise_prior
    assert (float(noise_prior.concentration), float(noise_prior.rate)) == pytest.approx((1.1, 0.05))
    assert opt.lengthscales().shape == (4,)
    default = filled("bo-lei-default", 4, 6, **FAST)
    assert not isinstance(default.model().covar_module, ScaleKernel)  # today's RBF default


def test_predict_is_in_objective_units():
    opt = filled("bo-lei", 2, 10, **FAST)
    x, y, _ = opt.train_data()
    opt2 = make_optimizer("bo-lei", 2, seed=0, **FAST)
    opt2.observe(x, 1000.0 + 50.0 * y)
    mean, std = opt2.predict(x)
    assert mean.shape == std.shape == (10,)
    np.testing.assert_allclose(mean, 1000.0 + 50.0 * y, atol=5.0)


@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"acquisition": "pi"}, "acquisition"),
        ({"kappa": -1.0}, "kappa"),
        ({"model_preset": "fancy"}, "model_preset"),
        ({"n_initial": 1}, "n_initial"),
        ({"num_restarts": 0}, "num_restarts"),
        ({"bogus": 1}, "bogus"),
        ({"space": "levels"}, "levels"),
        ({"trust_region": "yes"}, "trust_region"),
        ({"distinct": True}, "levels"),
        ({"trust_region": True, "space": "levels", "levels": 3, "horizon": 3}, "trust_region"),
    ],
)
def test_bad_settings_raise_a_clear_value_error(settings, match):
    with pytest.raises(ValueError, match=match):
        make_optimizer("bo-lei", 3, seed=0, **settings)


def test_unknown_method_and_bad_observations_are_refused():
    with pytest.raises(SettingsError, match="unknown method 'nope'"):
        make_optimizer("nope", 3, seed=0)
    with pytest.raises(ValueError, match="cem"):
        make_optimizer("cem", 3, seed=0, kappa=1.0)
    opt = make_optimizer("bo-lei", 3, seed=0)
    with pytest.raises(ValueError, match="outside"):
        opt.observe([0.1, 1.5, 0.2], 1.0)
    with pytest.raises(ValueError, match="finite"):
        opt.observe([0.1, 0.5, 0.2], float("nan"))
    with pytest.raises(ValueError, match="SEM"):
        opt.observe([0.1, 0.5, 0.2], 1.0, sem=-1.0)
    with pytest.raises(ValueError, match="shape"):
        opt.observe([0.1, 0.5], 1.0)
    assert opt.n_observed == 0
    assert set(METHODS) >= {"bo-lei", "bo-ucb", "cem", "random", "optuna-tpe", "optuna-gp"}


def test_new_experiments_default_to_the_optimisers_default_method():
    from app.optim import DEFAULT_METHOD
    from app.service.schemas import ExperimentCreate

    assert DEFAULT_METHOD in METHODS
    spec = ExperimentCreate(name="x", task="throw", levels=5)
    assert spec.method == DEFAULT_METHOD


def test_handful_bo_suggests_unseen_grid_points_and_rebuilds_identically():
    settings = {"levels": 2, "raw_samples": 64, "num_restarts": 2, "fit_maxiter": 20}
    opt = live("bo-levels", 11, 13, seed=2, **settings)
    policy = Policy(levels=2, with_release=True)
    seen = {tuple(r) for r in policy.grid_from_theta(opt.train_data()[0]).tolist()}
    x = opt.suggest(1)
    assert tuple(policy.grid_from_theta(x)[0].tolist()) not in seen
    rebuilt = make_optimizer("bo-levels", 11, seed=2, **settings)
    rebuilt.observe_many([Observation(o.theta, o.value) for o in opt.observations])
    np.testing.assert_array_equal(x, rebuilt.suggest(1))
    x2 = opt.suggest(1, pending=x)
    assert not np.array_equal(policy.grid_from_theta(x2), policy.grid_from_theta(x))
    assert opt.lengthscales().shape == (11,)


def test_anchor_sizes_step_by_every_then_by_a_fraction_of_n():
    from app.optim.bo import anchor_size

    anchors = sorted({anchor_size(n, 10, 0.1) for n in range(2, 600)})
    assert anchors[:4] == [2, 12, 22, 32]
    steps = np.diff(anchors)
    assert (steps >= 10).all() and (np.diff(steps) >= 0).all()
    assert anchor_size(500, 10, 0.1) == 489  # ... 403, 444, 489, 538: one full fit in ~50
    assert [anchor_size(n, 1, 0.0) for n in (2, 3, 17)] == [2, 3, 17]  # every trial: "full"


def _mll(model) -> float:
    from gpytorch.mlls import ExactMarginalLogLikelihood

    mll = ExactMarginalLogLikelihood(model.likelihood, model)
    model.train()
    with torch.no_grad():
        out = mll(model(*model.train_inputs), model.train_targets).item()
    model.eval()
    return out


def test_warm_fits_reach_the_full_fits_likelihood_and_rebuild_the_same(monkeypatch):
    """fit_mode="warm" starts each fit from the last anchor's hyperparameters: its marginal
    likelihood is the from-scratch fit's (to 1 %), and it is a function of the data alone."""
    import app.optim.bo as bo

    starts: list[tuple[int, np.ndarray]] = []  # (N, raw lengthscales) each fit started from
    real_fit = bo.fit_gp

    def recording_fit(model, maxiter=None):
        ls = model.covar_module.base_kernel.raw_lengthscale.detach().numpy().copy()
        starts.append((model.train_targets.shape[-1], ls))
        return real_fit(model, maxiter)

    monkeypatch.setattr(bo, "fit_gp", recording_fit)
    dim, n = 5, 47  # anchors 2, 12, 22, 32, 42: the model at 47 is a warm fit
    x = np.random.default_rng(3).random((n, dim))
    y = [bumpy(v) for v in x]
    live_warm = make_optimizer("bo-lei", dim, seed=0, fit_mode="warm")
    for i in range(n):  # observe one by one, asking for the model now and then (as a sweep)
        live_warm.observe(x[i], y[i])
        if i >= 40:
            live_warm.model()
    assert live_warm._anchor is not None and live_warm._anchor[0] == 42
    fitted_at_42 = live_warm._anchor[1]["covar_module.base_kernel.raw_lengthscale"].numpy()
    assert [k for k, _ in starts] == [32, 41, 42, 43, 44, 45, 46, 47]  # 41 needs 32's anchor
    np.testing.assert_array_equal(starts[-1][1], fitted_at_42)  # 47 started from 42's fit
    assert not np.allclose(starts[2][1], fitted_at_42)  # 42 itself: from the priors' defaults
    n_fits = len(starts)

    full = make_optimizer("bo-lei", dim, seed=0)
    rebuilt = make_optimizer("bo-lei", dim, seed=0, fit_mode="warm")
    for opt in (full, rebuilt):
        opt.observe(x, y)
    rebuilt.model()
    assert [k for k, _ in starts[n_fits:]] == [42, 47]  # a rebuild pays for its anchor once
    m_full, m_warm = _mll(full.model()), _mll(live_warm.model())
    assert m_warm >= m_full - 0.01 * abs(m_full), (m_warm, m_full)
    probe = np.random.default_rng(4).random((20, dim))
    mean_l, std_l = live_warm.predict(probe)
    mean_r, std_r = rebuilt.predict(probe)
    np.testing.assert_allclose(mean_l, mean_r, atol=1e-9)
    np.testing.assert_allclose(std_l, std_r, atol=1e-9)
    mean_f, _ = full.predict(probe)
    assert np.corrcoef(mean_f, mean_l)[0, 1] > 0.99


@pytest.mark.parametrize(
    "settings",
    [
        {"fit_mode": "quick"},
        {"refit_every": 0},
        {"refit_every": 2.5},
        {"refit_fraction": -1},
        {"warm_maxiter": -1},
        {"acq_posterior": "lazy"},
    ],
)
def test_bad_fit_settings_name_the_setting(settings):
    name = next(iter(settings))
    with pytest.raises(SettingsError, match=name):
        make_optimizer("bo-lei", 4, seed=0, **settings)
