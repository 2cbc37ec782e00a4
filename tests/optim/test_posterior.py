"""The cached exact posterior (``app.optim.posterior``) against BoTorch's, and BO with it."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from botorch.acquisition.analytic import LogExpectedImprovement, UpperConfidenceBound

import app.optim.bo as bo
from app.optim import make_optimizer
from app.optim.posterior import CachedLogEI, CachedUCB, ExactPosterior

FAST = {"num_restarts": 4, "raw_samples": 128}


def bumpy(theta: np.ndarray) -> float:
    th = np.asarray(theta)
    return float(np.exp(-8.0 * np.sum((th - 0.3) ** 2)) + 0.1 * np.sin(5.0 * th.sum()))


def filled(method: str, dim: int, n: int, seed: int = 0, **settings):
    opt = make_optimizer(method, dim, seed=seed, **settings)
    x = np.random.default_rng(seed).random((n, dim))
    opt.observe(x, [bumpy(v) for v in x])
    return opt


@pytest.mark.parametrize("method, kind", [("bo-lei", "matern52"), ("bo-lei-default", "rbf")])
def test_moments_values_and_gradients_are_botorchs(method, kind):
    """Mean and variance at 64 points, LogEI and UCB and their gradients in x: BoTorch's,
    to round-off, for the paper's Matérn GP and today's default RBF GP."""
    opt = filled(method, 6, 60)
    model = opt.model()
    exact = ExactPosterior.of(model)
    assert exact is not None and exact.kind == kind
    x = torch.rand(64, 1, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        post = model.posterior(x)
        mean, var = exact.mean_var(x.squeeze(-2))
    np.testing.assert_allclose(mean, post.mean.reshape(-1), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(var, post.variance.reshape(-1), rtol=1e-7, atol=1e-12)
    best = float(opt.train_data()[1].max())
    pairs = [
        (LogExpectedImprovement(model, best_f=best), CachedLogEI(model, best, exact)),
        (UpperConfidenceBound(model, beta=0.9), CachedUCB(model, 0.9, exact)),
    ]
    for theirs, ours in pairs:
        values, grads = [], []
        for acq in (theirs, ours):
            xg = x.clone().requires_grad_(True)
            v = acq(xg)
            (g,) = torch.autograd.grad(v.sum(), xg)
            values.append(v.detach())
            grads.append(g)
        np.testing.assert_allclose(values[1], values[0], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(grads[1], grads[0], rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("method", ["bo-lei", "bo-lei-default"])
def test_closed_form_moment_gradients_pass_gradcheck_even_on_the_data(method):
    """``mean_var``'s written-out gradient against finite differences (torch's gradcheck), at
    random points and at the training inputs themselves (r = 0 for every Matérn term there);
    with a gradient the variance comes from K⁻¹ k, without from ‖L⁻¹ k‖²: the same values."""
    opt = filled(method, 5, 40)
    exact = ExactPosterior.of(opt.model())
    assert exact is not None
    x_train = torch.as_tensor(opt.train_data()[0][:4])
    x = torch.cat([torch.rand(6, 5, dtype=torch.float64), x_train]).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda v: exact.mean_var(v), (x,), eps=1e-6, atol=1e-5)
    mean_g, var_g = exact.mean_var(x)
    with torch.no_grad():
        mean, var = exact.mean_var(x)
    np.testing.assert_allclose(mean_g.detach(), mean, rtol=1e-12)
    np.testing.assert_allclose(var_g.detach(), var, rtol=1e-6, atol=1e-10)
    assert var[6:].max() < var[:6].min()  # the training inputs: the least variance left


def test_closed_form_log_ei_gradient_holds_deep_in_the_tails():
    """LogEI of the moments, gradient written out (d log h/du = Φ(u)/h(u)): gradcheck from
    u = −60 (an improvement 60 σ away) to u = +30, and at a variance below the clamp, where
    the variance gets no gradient."""
    from app.optim.posterior import _LogEIOfMoments

    mean = torch.linspace(-60.0, 30.0, 19, dtype=torch.float64).requires_grad_(True)
    var = torch.full((19,), 1.0, dtype=torch.float64).requires_grad_(True)
    best = torch.zeros(19, dtype=torch.float64)
    for sign in (1.0, -1.0):
        assert torch.autograd.gradcheck(
            lambda m, v, sign=sign: _LogEIOfMoments.apply(m, v, best, sign, 1e-12),
            (mean, var),
            eps=1e-6,
            atol=1e-6,
        )
    tiny = torch.tensor([1e-14], dtype=torch.float64, requires_grad=True)
    value = _LogEIOfMoments.apply(torch.tensor([0.5]).double(), tiny, best[:1], 1.0, 1e-12)
    (g,) = torch.autograd.grad(value.sum(), tiny)
    assert g.item() == 0.0 and torch.isfinite(value).all()


def test_unsupported_models_keep_botorchs_posterior():
    """Per-point noise (data weighed by age) is not the cached posterior's: ``of`` says None,
    and BO with ``acq_posterior="cached"`` still suggests, through BoTorch's LogEI."""
    aged = filled("bo-lei", 4, 20, age_halflife_trials=10.0, acq_posterior="cached", **FAST)
    assert ExactPosterior.of(aged.model()) is None
    acq = aged._acquisition(aged.model(), None, 1, 0)
    assert type(acq) is LogExpectedImprovement
    assert aged.suggest(1).shape == (1, 4)


@pytest.mark.parametrize("acquisition", ["logei", "ucb"])
def test_bo_with_the_cached_posterior_suggests_what_botorchs_does(acquisition):
    """Same data, same seed: the suggestion with ``acq_posterior="cached"`` is BoTorch's."""
    got = []
    for posterior in ("botorch", "cached"):
        opt = filled("bo-lei", 5, 30, acquisition=acquisition, acq_posterior=posterior, **FAST)
        acq = opt._acquisition(opt.model(), None, 1, 0)
        assert isinstance(acq, (CachedLogEI, CachedUCB)) == (posterior == "cached")
        got.append(opt.suggest(1)[0])
    np.testing.assert_allclose(got[1], got[0], atol=1e-5)


def test_warm_maxiter_zero_conditions_on_the_anchors_hyperparameters(monkeypatch):
    """``warm_maxiter=0``: between anchors no fit runs at all; the model has the anchor's
    hyperparameters exactly and all the data; a rebuilt optimiser agrees with the live one."""
    calls: list[int] = []
    real_fit = bo.fit_gp

    def counting_fit(model, maxiter=None):
        calls.append(model.train_targets.shape[-1])
        return real_fit(model, maxiter)

    monkeypatch.setattr(bo, "fit_gp", counting_fit)
    dim, n = 4, 47  # anchors ..., 32, 42: 43-47 are conditioned on 42's fit
    x = np.random.default_rng(5).random((n, dim))
    y = [bumpy(v) for v in x]
    live = make_optimizer("bo-lei", dim, seed=0, fit_mode="warm", warm_maxiter=0)
    for i in range(n):
        live.observe(x[i], y[i])
        if i >= 40:
            live.model()
    assert calls == [32, 42]  # 41 needs 32's anchor; 42 is one; 43..47 fit nothing
    anchor = live._anchor[1]
    model = live.model()
    assert model.train_targets.shape[-1] == n
    for name, value in model.named_parameters():
        np.testing.assert_array_equal(value.detach().numpy(), anchor[name].numpy())
    rebuilt = make_optimizer("bo-lei", dim, seed=0, fit_mode="warm", warm_maxiter=0)
    rebuilt.observe(x, y)
    probe = np.random.default_rng(6).random((10, dim))
    np.testing.assert_allclose(rebuilt.predict(probe)[0], live.predict(probe)[0], atol=1e-9)


def test_a_fit_that_fails_every_attempt_keeps_its_result_instead_of_failing(monkeypatch):
    """When BoTorch's fit ends every attempt in an optimiser warning (ModelFittingError: seen
    on a hammering run at N = 403), the fit is taken as it stands and BO still suggests."""
    from botorch.exceptions.errors import ModelFittingError

    real = bo.fit_gpytorch_mll
    calls: list[bool] = []

    def strict_fails(mll, **kwargs):
        lenient = "warning_handler" in kwargs
        calls.append(lenient)
        if not lenient:
            raise ModelFittingError("All attempts to fit the model have failed.")
        return real(mll, **kwargs)

    monkeypatch.setattr(bo, "fit_gpytorch_mll", strict_fails)
    opt = filled("bo-lei", 4, 20, **FAST)
    fitted = opt.model()
    default = bo.build_gp(*opt._train_tensors(), "paper")
    ls = fitted.covar_module.base_kernel.lengthscale.detach()
    assert not torch.allclose(ls, default.covar_module.base_kernel.lengthscale.detach())
    assert calls == [False, True]
    assert opt.suggest(1).shape == (1, 4)

    def always_fails(mll, **kwargs):
        raise ModelFittingError("All attempts to fit the model have failed.")

    monkeypatch.setattr(bo, "fit_gpytorch_mll", always_fails)
    stuck = filled("bo-lei", 4, 20, **FAST)
    assert stuck.suggest(1).shape == (1, 4)  # the priors' defaults, unfitted: still a suggestion
