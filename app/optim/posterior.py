"""The exact GP posterior of a fitted ``SingleTaskGP``, factorised once per suggestion, for the
analytic acquisitions (LogEI, UCB) that BO's search evaluates ~100 times per suggestion.

BoTorch's ``model.posterior`` rebuilds the training covariance and its factor, through
GPyTorch's lazy tensors, at every evaluation; the arithmetic is small (N ≤ 500 points, a
batch of 10 restarts) and the overhead is most of an acquisition search's cost. Here the
hyperparameters are read once, ``K = s·k(X, X) + σ²I`` is factorised once (the same
``psd_safe_cholesky`` GPyTorch uses), and each evaluation is plain torch:

    mean(x) = μ_y + σ_y (c + k(x, X) α),  var(x) = σ_y² (s − ‖L⁻¹ k(X, x)‖²)

with α = K⁻¹ (y − c) on the standardised outcomes. The same mathematics as BoTorch's
posterior; results agree to round-off (tests/optim/test_posterior.py). Supported: ARD Matérn-5/2
or RBF kernels, optionally in a ScaleKernel; a constant mean; a Gaussian likelihood with one
learned noise; ``Normalize`` and ``Standardize`` transforms. Anything else (multitask GPs,
per-point noise) is ``None`` from ``ExactPosterior.of`` and the caller keeps BoTorch's path.
"""

from __future__ import annotations

import math

import torch
from botorch.acquisition.analytic import LogExpectedImprovement, UpperConfidenceBound
from botorch.models import SingleTaskGP
from botorch.models.transforms import Normalize, Standardize
from gpytorch.kernels import MaternKernel, RBFKernel, ScaleKernel
from gpytorch.likelihoods import GaussianLikelihood
from gpytorch.means import ConstantMean
from linear_operator.utils.cholesky import psd_safe_cholesky
from torch import Tensor


class ExactPosterior:
    """Mean and variance (objective units) of a fitted GP at (..., d) inputs, factorised once."""

    def __init__(self, model: SingleTaskGP, kind: str, lengthscale: Tensor, scale: Tensor) -> None:
        self.model, self.kind = model, kind
        self.lengthscale, self.scale = lengthscale, scale  # (d,), ()
        with torch.no_grad():
            x = model.train_inputs[0]  # (N, d), already through the input transform
            self.x_train = x
            self.x_scaled = x / lengthscale  # (N, d)
            self.x_sq = self.x_scaled.pow(2).sum(-1)  # (N,)
            y = model.train_targets  # (N,) standardised
            c = model.mean_module.constant.detach().reshape(())
            noise = model.likelihood.noise.detach().reshape(())
            k = self._kernel(x, x) + noise * torch.eye(len(x), dtype=x.dtype)
            self.chol = psd_safe_cholesky(k)
            self.alpha = torch.cholesky_solve((y - c).unsqueeze(-1), self.chol).squeeze(-1)
            eye = torch.eye(len(x), dtype=x.dtype)
            # L⁻ᵀ, contiguous: k(x, X) L⁻ᵀ is a plain matmul, forward and backward
            self.chol_inv_t = torch.linalg.solve_triangular(
                self.chol, eye, upper=False
            ).mT.contiguous()
            self.const = c
            tf = model.outcome_transform
            self.y_mean = tf.means.detach().reshape(())
            self.y_std = tf.stdvs.detach().reshape(())
            # the input transform as an affine map, when it is one (Normalize): x' = (x − o) / c
            itf = getattr(model, "input_transform", None)
            self.affine: tuple[Tensor, Tensor] | None = None
            if itf is None:
                self.affine = (torch.zeros(()), torch.ones(()))
            elif isinstance(itf, Normalize) and getattr(itf, "indices", None) is None:
                self.affine = (
                    itf.offset.detach().reshape(-1),
                    itf.coefficient.detach().reshape(-1),
                )

    @classmethod
    def of(cls, model: object) -> ExactPosterior | None:
        """The cached posterior of ``model``, or None where it is not a supported GP."""
        if type(model) is not SingleTaskGP or getattr(model, "num_outputs", 1) != 1:
            return None
        if not isinstance(model.likelihood, GaussianLikelihood) or type(model.likelihood) is not (
            GaussianLikelihood
        ):
            return None
        if not isinstance(model.mean_module, ConstantMean):
            return None
        if not isinstance(getattr(model, "outcome_transform", None), Standardize):
            return None
        covar = model.covar_module
        scale = torch.ones((), dtype=torch.float64)
        if isinstance(covar, ScaleKernel):
            scale = covar.outputscale.detach().reshape(())
            covar = covar.base_kernel
        if isinstance(covar, MaternKernel) and covar.nu == 2.5:
            kind = "matern52"
        elif type(covar) is RBFKernel:
            kind = "rbf"
        else:
            return None
        if covar.active_dims is not None:
            return None
        lengthscale = covar.lengthscale.detach().reshape(-1)
        return cls(model, kind, lengthscale, scale)

    def _kernel(self, a: Tensor, b: Tensor) -> Tensor:
        """s·k(a, b): (..., n, d) × (m, d) → (..., n, m)."""
        return self._kernel_sq(self._sq_dist(a / self.lengthscale, b / self.lengthscale))

    @staticmethod
    def _sq_dist(a: Tensor, b: Tensor, b_sq: Tensor | None = None) -> Tensor:
        """Squared distances (..., n, m) of scaled points a (..., n, d) and b (m, d)."""
        b_sq = b.pow(2).sum(-1) if b_sq is None else b_sq
        sq = a.pow(2).sum(-1, keepdim=True) + b_sq - 2.0 * (a @ b.mT)
        return sq.clamp_min(0.0)

    def _kernel_sq(self, sq: Tensor) -> Tensor:
        """s·k as a function of the scaled squared distance."""
        if self.kind == "rbf":
            return self.scale * torch.exp(-0.5 * sq)
        d = sq.clamp_min(1e-30).sqrt()
        return (
            self.scale
            * (1.0 + math.sqrt(5.0) * d + (5.0 / 3.0) * sq)
            * torch.exp(-math.sqrt(5.0) * d)
        )

    def mean_var(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Posterior mean and variance (objective units) at ``x`` (..., d): each (...,)."""
        if self.affine is None:
            x = self.model.transform_inputs(x)
        else:
            x = (x - self.affine[0]) / self.affine[1]
        x = x / self.lengthscale
        ks = self._kernel_sq(self._sq_dist(x, self.x_scaled, self.x_sq))  # (..., N)
        mean = self.const + ks @ self.alpha
        v = ks @ self.chol_inv_t  # (L⁻¹ k(X, x))ᵀ
        var = self.scale - v.pow(2).sum(-1)
        return self.y_mean + self.y_std * mean, self.y_std.pow(2) * var


class _CachedMoments:
    """Replaces an analytic acquisition's posterior moments by ``ExactPosterior``'s."""

    _exact: ExactPosterior

    def _mean_and_sigma(
        self, X: Tensor, compute_sigma: bool = True, min_var: float = 1e-12
    ) -> tuple[Tensor, Tensor | None]:
        mean, var = self._exact.mean_var(X.squeeze(-2))  # (b, 1, d) → (b,)
        mean = mean.unsqueeze(-1)  # (b, m = 1), as BoTorch's
        if not compute_sigma:
            return mean, None
        return mean, var.unsqueeze(-1).clamp_min(min_var).sqrt()


class CachedLogEI(_CachedMoments, LogExpectedImprovement):
    """BoTorch's LogEI on ``ExactPosterior``'s moments."""

    def __init__(self, model: SingleTaskGP, best_f: float, exact: ExactPosterior) -> None:
        super().__init__(model, best_f=best_f)
        self._exact = exact


class CachedUCB(_CachedMoments, UpperConfidenceBound):
    """BoTorch's UCB (μ + √β σ) on ``ExactPosterior``'s moments."""

    def __init__(self, model: SingleTaskGP, beta: float, exact: ExactPosterior) -> None:
        super().__init__(model, beta=beta)
        self._exact = exact
