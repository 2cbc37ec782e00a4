"""Bayesian optimisation with BoTorch behind the ask/tell protocol.

The GP is rebuilt and refit (``fit_gpytorch_mll``) from all observations whenever a suggestion
or prediction needs it, so a rebuilt optimiser and a live one give the same answers.

Two search representations:
  * ``space="theta"`` (the paper): the GP models J(θ) on the unit box [0,1]^D directly.
  * ``space="levels"`` (handful's variant): each θ_i is decoded to the six paired-command levels
    of its action (``g``'s digits, each scaled to [0,1]) and the release step to [0,1], so the
    GP sees pressures rather than action indices; the acquisition is optimised over the level
    grid by discrete local search and the result is mapped back to the centre of its θ bin.

Reads no environment and sets no process-wide state: torch's thread count is the entry
point's choice (``app.procs.set_torch_threads``: the server, the sweep, the benchmarks).
"""

from __future__ import annotations

import contextlib
import math
import threading
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from botorch.acquisition import (
    AcquisitionFunction,
    LogExpectedImprovement,
    qLogNoisyExpectedImprovement,
    qUpperConfidenceBound,
)
from botorch.acquisition.analytic import UpperConfidenceBound
from botorch.exceptions.errors import ModelFittingError
from botorch.fit import fit_gpytorch_mll
from botorch.models import MultiTaskGP, SingleTaskGP
from botorch.models.transforms import Normalize, Standardize
from botorch.models.utils.gpytorch_modules import (
    get_gaussian_likelihood_with_gamma_prior,
    get_matern_kernel_with_gamma_prior,
)
from botorch.optim import optimize_acqf, optimize_acqf_discrete_local_search
from botorch.sampling import SobolQMCNormalSampler
from gpytorch.likelihoods import FixedNoiseGaussianLikelihood
from gpytorch.mlls import ExactMarginalLogLikelihood

from app.optim.base import Optimizer, SettingsError, Surrogate, call_seed
from app.optim.posterior import CachedLogEI, CachedUCB, ExactPosterior
from app.policy import N_PAIRED, Policy, PolicyError

ACQUISITIONS = ("logei", "ucb", "qlognei")
MODEL_PRESETS = ("paper", "default")
SPACES = ("theta", "levels")
INITIAL_DESIGNS = ("sobol", "corners")
FIT_MODES = ("full", "warm")
#: how the analytic acquisitions (LogEI, UCB) get the GP's posterior: BoTorch's, or
#: ``app.optim.posterior``'s, factorised once per suggestion (the same numbers, to round-off)
ACQ_POSTERIORS = ("botorch", "cached")

DTYPE = torch.float64
#: L-BFGS-B cap of a multitask GP's fit when ``fit_maxiter`` is None. Uncapped, a fit on 72
#: prior + 10 own points (D = 11, a quadratic test function) ran 675 iterations, about 19 s
#: on a loaded core; capped at 200 it took a quarter of that and its predictions correlated
#: with the truth within 0.001 of the uncapped fit's (0.984 vs 0.985; paper preset 0.963 vs
#: 0.964).
MULTITASK_FIT_MAXITER = 200
# Torch's RNG is process-global; fork it per call under a lock so threads cannot interleave.
_TORCH_RNG_LOCK = threading.Lock()


@dataclass(frozen=True)
class BOSettings:
    """Validated BO settings (see ``BayesOpt``)."""

    acquisition: str = "logei"
    kappa: float = 0.9
    n_initial: int | None = None
    model_preset: str = "paper"
    num_restarts: int = 10
    raw_samples: int = 512
    mc_samples: int = 128
    space: str = "theta"
    levels: int | None = None
    horizon: int = 10
    initial_design: str = "sobol"
    corner_prob: float = 0.5
    fit_maxiter: int | None = None
    trust_region: bool = False
    distinct: bool = False
    fit_mode: str = "full"
    refit_every: int = 10
    refit_fraction: float = 0.1
    warm_maxiter: int = 20
    acq_posterior: str = "botorch"
    age_halflife_trials: float | None = None


#: integer settings and their sane ranges (beyond them a suggestion costs minutes or more)
SETTING_RANGES: dict[str, tuple[int, int]] = {
    "num_restarts": (1, 64),
    "raw_samples": (1, 8192),
    "mc_samples": (1, 4096),
    "horizon": (1, 100),
    "fit_maxiter": (1, 10_000),
    "n_initial": (2, 10_000),
    "refit_every": (1, 10_000),
    "warm_maxiter": (0, 10_000),
}


def _check_settings(dim: int, settings: dict[str, Any]) -> BOSettings:
    known = set(BOSettings.__dataclass_fields__)
    unknown = sorted(set(settings) - known)
    if unknown:
        raise SettingsError(
            f"unknown BO setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
        )
    s = BOSettings(**settings)
    if s.acquisition not in ACQUISITIONS:
        raise SettingsError(f"acquisition must be one of {ACQUISITIONS}, got {s.acquisition!r}")
    if s.model_preset not in MODEL_PRESETS:
        raise SettingsError(f"model_preset must be one of {MODEL_PRESETS}, got {s.model_preset!r}")
    if s.space not in SPACES:
        raise SettingsError(f"space must be one of {SPACES}, got {s.space!r}")
    if s.initial_design not in INITIAL_DESIGNS:
        raise SettingsError(
            f"initial_design must be one of {INITIAL_DESIGNS}, got {s.initial_design!r}"
        )
    if not (isinstance(s.kappa, int | float) and math.isfinite(s.kappa) and s.kappa >= 0):
        raise SettingsError(f"kappa must be a finite number ≥ 0, got {s.kappa!r}")
    for name, (low, high) in SETTING_RANGES.items():
        v = getattr(s, name)
        if v is None and name in ("fit_maxiter", "n_initial"):
            continue
        if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
            raise SettingsError(f"{name} must be an integer in {low}..{high}, got {v!r}")
    if s.fit_mode not in FIT_MODES:
        raise SettingsError(f"fit_mode must be one of {FIT_MODES}, got {s.fit_mode!r}")
    if s.acq_posterior not in ACQ_POSTERIORS:
        raise SettingsError(
            f"acq_posterior must be one of {ACQ_POSTERIORS}, got {s.acq_posterior!r}"
        )
    if not (
        isinstance(s.refit_fraction, int | float)
        and not isinstance(s.refit_fraction, bool)
        and 0.0 <= s.refit_fraction <= 10.0
    ):
        raise SettingsError(f"refit_fraction must be a number in [0, 10], got {s.refit_fraction!r}")
    if not isinstance(s.trust_region, bool):
        raise SettingsError(f"trust_region must be true or false, got {s.trust_region!r}")
    if s.trust_region and s.space != "theta":
        raise SettingsError("trust_region needs space='theta'")
    h = s.age_halflife_trials
    if h is not None and (
        isinstance(h, bool) or not isinstance(h, int | float) or not math.isfinite(h) or h <= 0
    ):
        raise SettingsError(
            f"age_halflife_trials must be a number of trials > 0 or None (off), got {h!r}"
        )
    if not isinstance(s.distinct, bool):
        raise SettingsError(f"distinct must be true or false, got {s.distinct!r}")
    if not 0.0 <= s.corner_prob <= 1.0:
        raise SettingsError(f"corner_prob must be in [0, 1], got {s.corner_prob!r}")
    if s.space == "levels" or s.initial_design == "corners" or s.distinct:
        if s.levels is None or isinstance(s.levels, bool) or not isinstance(s.levels, int):
            raise SettingsError(
                "space='levels', initial_design='corners' and distinct need levels=P "
                "(an integer ≥ 2)"
            )
        if s.levels < 2:
            raise SettingsError(f"levels (P) must be an integer ≥ 2, got {s.levels}")
        if dim not in (s.horizon, s.horizon + 1):
            raise SettingsError(
                f"dim {dim} must be horizon ({s.horizon}) or horizon + 1 (with release step)"
            )
    return s


@dataclass(frozen=True)
class TrustRegion:
    """TuRBO-1's state (Eriksson et al., 2019): the box's base side ``length`` in [0,1]^D units
    and the current run of successes or failures."""

    length: float
    successes: int
    failures: int


TR_LENGTH_INIT, TR_LENGTH_MIN, TR_LENGTH_MAX = 0.8, 0.5**7, 1.6
TR_SUCCESS_TOL = 3


def trust_region_state(y: np.ndarray, n_initial: int, dim: int) -> TrustRegion:
    """Replay TuRBO-1's rule over the observations ``y`` (N,) in order, one per step.

    After the ``n_initial`` design points, an observation that beats the best so far by
    more than 1e-3·|best| is a success, anything else a failure. ``TR_SUCCESS_TOL``
    successes in a row double the length (up to ``TR_LENGTH_MAX``); max(4, D) failures in a
    row halve it; below ``TR_LENGTH_MIN`` the region restarts at ``TR_LENGTH_INIT``. A pure
    function of the data, so a rebuilt optimiser has the same region as a live one.
    """
    fail_tol = max(4, dim)
    length, successes, failures = TR_LENGTH_INIT, 0, 0
    y = np.asarray(y, dtype=np.float64)
    if len(y) <= n_initial:
        return TrustRegion(length, 0, 0)
    best = float(np.max(y[:n_initial]))
    for v in y[n_initial:]:
        if v > best + 1e-3 * abs(best):
            successes, failures = successes + 1, 0
        else:
            successes, failures = 0, failures + 1
        best = max(best, float(v))
        if successes == TR_SUCCESS_TOL:
            length, successes = min(2.0 * length, TR_LENGTH_MAX), 0
        elif failures == fail_tol:
            length, failures = length / 2.0, 0
        if length < TR_LENGTH_MIN:
            length, successes, failures = TR_LENGTH_INIT, 0, 0
    return TrustRegion(length, successes, failures)


def anchor_size(n: int, every: int, fraction: float) -> int:
    """The largest anchor ≤ ``n``: the observation counts at which a ``fit_mode="warm"`` GP is
    fitted from scratch. Anchors start at 2 and step by ``max(every, ceil(fraction · a))``, so
    full fits thin out as the data grows (at N = 500 with 10 / 0.1: every 50 trials)."""
    a = 2
    while True:
        nxt = a + max(every, math.ceil(fraction * a))
        if nxt > n:
            return a
        a = nxt


def age_noise(n: int, halflife: float) -> np.ndarray:
    """(n,) extra noise variance, in units of the observations' variance, of observations
    0 .. n-1 (oldest first) when data are weighed by age: 2^(a / halflife) − 1 for an
    observation a trials old (a = n-1-i). The newest adds nothing; one ``halflife`` trials old
    adds as much noise as the data's whole spread, and it doubles (plus one) every halflife."""
    ages = np.arange(n - 1, -1, -1, dtype=np.float64)
    return np.exp2(ages / float(halflife)) - 1.0


def _extra_noise_likelihood(noise: torch.Tensor, model_preset: str) -> FixedNoiseGaussianLikelihood:
    """A likelihood with known per-point noise (standardised units) plus a learned
    homoskedastic noise (the ``paper`` preset's Gamma(1.1, 0.05) prior on it)."""
    kwargs: dict[str, Any] = {}
    if model_preset == "paper":
        from gpytorch.priors import GammaPrior

        kwargs["noise_prior"] = GammaPrior(1.1, 0.05)
    return FixedNoiseGaussianLikelihood(
        noise=noise.clamp_min(1e-6), learn_additional_noise=True, **kwargs
    )


def build_gp(
    train_x: torch.Tensor,
    train_y: torch.Tensor,
    train_yvar: torch.Tensor | None,
    model_preset: str,
    extra_noise: torch.Tensor | None = None,
) -> SingleTaskGP:
    """A SingleTaskGP on (N, F) inputs in [0,1] and (N, 1) outcomes; not yet fitted.

    ``paper``: ARD Matérn-5/2 in a ScaleKernel with BoTorch's older Gamma priors
    (lengthscale Gamma(3, 6), outputscale Gamma(2, 0.15), noise Gamma(1.1, 0.05)).
    ``default``: today's SingleTaskGP default (RBF, dimension-scaled LogNormal priors).
    ``extra_noise`` (N,): known noise variance per point in standardised units (weighing by
    age, ``age_noise``), on top of a learned noise; ``train_yvar`` is then folded into it.
    """
    f = train_x.shape[-1]
    kwargs: dict[str, Any] = {
        "input_transform": Normalize(d=f, bounds=_unit_bounds(f)),
        "outcome_transform": Standardize(m=1),
    }
    if model_preset == "paper":
        kwargs["covar_module"] = get_matern_kernel_with_gamma_prior(ard_num_dims=f)
        if train_yvar is None:
            kwargs["likelihood"] = get_gaussian_likelihood_with_gamma_prior()
    if extra_noise is not None:
        noise = extra_noise.reshape(-1)
        if train_yvar is not None:
            noise = noise + train_yvar.reshape(-1) / train_y.var().clamp_min(1e-12)
            train_yvar = None
        kwargs["likelihood"] = _extra_noise_likelihood(noise, model_preset)
    return SingleTaskGP(train_x, train_y, train_yvar, **kwargs)


def build_multitask_gp(
    prior_x: torch.Tensor,
    prior_y: torch.Tensor,
    train_x: torch.Tensor,
    train_y: torch.Tensor,
    model_preset: str,
    extra_noise: torch.Tensor | None = None,
) -> MultiTaskGP:
    """BoTorch's MultiTaskGP over (θ features, source): the prior's (M, F) inputs and (M, 1)
    outcomes as task 0, the optimiser's own (N, F) and (N, 1) as task 1, the model's only
    output (its posterior is task 1's). Both tasks share one input kernel (``paper``: the
    Matérn-5/2 with Gamma priors; ``default``: BoTorch's); a rank-1 positive index kernel
    learns how the tasks correlate; each task has its own mean and (without ``extra_noise``)
    its own noise. Outcomes are standardised together. Not yet fitted.

    ``extra_noise`` (N,): known extra noise variance of the own observations (weighing by
    age); the prior's points get none; a learned homoskedastic noise comes on top."""
    f = train_x.shape[-1]
    x = torch.cat(
        [
            torch.cat([prior_x, torch.zeros(len(prior_x), 1, dtype=DTYPE)], dim=-1),
            torch.cat([train_x, torch.ones(len(train_x), 1, dtype=DTYPE)], dim=-1),
        ]
    )
    y = torch.cat([prior_y, train_y])
    kwargs: dict[str, Any] = {"output_tasks": [1], "all_tasks": [0, 1], "rank": 1}
    if model_preset == "paper":
        kwargs["covar_module"] = get_matern_kernel_with_gamma_prior(ard_num_dims=f)
    if extra_noise is not None:
        noise = torch.cat([torch.zeros(len(prior_x), dtype=DTYPE), extra_noise.reshape(-1)])
        kwargs["likelihood"] = _extra_noise_likelihood(noise, model_preset)
    return MultiTaskGP(x, y, task_feature=f, **kwargs)


def task_correlation(model: MultiTaskGP) -> float:
    """The learned correlation between a MultiTaskGP's tasks 0 and 1 (−1 .. 1)."""
    task_kernel = model.covar_module.kernels[1]
    with torch.no_grad():
        b = task_kernel.covar_matrix.to_dense()
    return float(b[0, 1] / torch.sqrt(b[0, 0] * b[1, 1]).clamp_min(1e-300))


def fit_gp(model: SingleTaskGP, maxiter: int | None = None) -> SingleTaskGP:
    """Fit the GP's hyperparameters by L-BFGS-B on the marginal likelihood (BoTorch retries).

    ``maxiter`` caps L-BFGS-B iterations (None: BoTorch's default).
    """
    mll = ExactMarginalLogLikelihood(model.likelihood, model)
    kwargs: dict[str, Any] = {}
    if maxiter is not None:
        kwargs["optimizer_kwargs"] = {"options": {"maxiter": maxiter}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            fit_gpytorch_mll(mll, **kwargs)
        except ModelFittingError:
            # every attempt ended in an optimiser warning (on skewed data, e.g. hammering at
            # N ≈ 400, L-BFGS-B's line search can stop abnormally from every start): take the
            # fit as it stands rather than fail the suggestion; if even that raises, the
            # hyperparameters stay where the fit started (BoTorch rolls them back)
            with contextlib.suppress(ModelFittingError):
                fit_gpytorch_mll(mll, warning_handler=lambda w: True, **kwargs)
    model.eval()
    return model


def _raw_hyperparameters(model: SingleTaskGP) -> dict[str, torch.Tensor]:
    """A fitted GP's raw hyperparameters (name → detached copy), to start another fit from."""
    return {k: v.detach().clone() for k, v in model.named_parameters()}


def _unit_bounds(f: int) -> torch.Tensor:
    return torch.stack([torch.zeros(f, dtype=DTYPE), torch.ones(f, dtype=DTYPE)])


class BayesOpt(Optimizer, Surrogate):
    """GP-based BO on [0,1]^dim.

    Settings:
        acquisition: "logei" (LogEI; qLogNEI when trials are pending, observations carry SEM
            or n > 1), "ucb" (μ + √κ σ: BoTorch's UCB with beta = κ; qUCB with pending or
            n > 1) or "qlognei" (always).
        kappa: κ of UCB (0.9).
        n_initial: Sobol initial trials before the GP is used (D + 1).
        model_preset: "paper" or "default" (see ``build_gp``).
        num_restarts, raw_samples: of the acquisition optimiser.
        mc_samples: QMC samples of the q-acquisitions.
        space: "theta" (paper) or "levels" (needs ``levels``; see the module docstring).
        levels, horizon: P and H of the policy, for ``space="levels"``.
        fit_maxiter: cap on the GP fit's L-BFGS-B iterations (None: BoTorch's default).
        initial_design: "sobol", or "corners" (Sobol on the level grid with each level pushed
            to its lowest/highest value with probability ``corner_prob``: bang-bang actions).
        trust_region: optimise the acquisition in TuRBO-1's box around the best observation,
            its sides scaled by the GP's lengthscales (see ``trust_region_state``).
        fit_mode: "full" (the paper: every GP fitted from the priors' defaults) or "warm" (fit
            from scratch every ``refit_every`` trials or ``refit_fraction`` of N, whichever is
            more; start every other fit from the last such fit's hyperparameters, for at most
            ``warm_maxiter`` L-BFGS-B iterations: near the optimum, more only wander along flat
            directions of the likelihood; 0: none, the anchor's hyperparameters as they are).
        acq_posterior: "botorch" (the paper) or "cached": LogEI and UCB read the posterior
            from ``app.optim.posterior.ExactPosterior``, factorised once per suggestion (the
            same numbers to round-off, about 3× cheaper to search; other acquisitions and
            models keep BoTorch's).
        distinct: never suggest θ whose schedule (``Policy.grid_from_theta``: the decoded
            levels and release step; needs ``levels``) was observed or is pending: the acquisition's
            best local optimum with a new schedule, else the best new one of its raw samples.
        age_halflife_trials: weigh data by age (None: off). An observation ``a`` trials older
            than the newest gets extra noise variance (2^(a/h) − 1)·Var(y) on top of the
            learned noise (``age_noise``), so the GP trusts old trials less as the robot drifts;
            prior data (multitask) are not aged.

    With a prior (``use_prior``, see ``app.optim.prior``): "warmstart" starts the Sobol design
    with the prior's best θ; "multitask" replaces the design by them (``n_initial`` becomes
    ``prior_top_k``, at least 1) and fits ``build_multitask_gp`` to prior and own data from the
    first own observation on (always fitted in full, whatever ``fit_mode``, for at most
    ``fit_maxiter`` or ``MULTITASK_FIT_MAXITER`` L-BFGS-B iterations).
    """

    method = "bo"

    def __init__(self, dim: int, *, seed: int, **settings: Any) -> None:
        super().__init__(dim, seed=seed)
        self.settings = _check_settings(self.dim, settings)
        s = self.settings
        self.n_initial = s.n_initial if s.n_initial is not None else self.dim + 1
        #: the policy's θ ↔ schedule codec, when the settings work on its level grid
        self.policy: Policy | None = None
        if s.space == "levels" or s.initial_design == "corners" or s.distinct:
            try:
                self.policy = Policy(
                    levels=s.levels or 2, horizon=s.horizon, with_release=self.dim > s.horizon
                )
            except PolicyError as exc:
                raise SettingsError(str(exc)) from None
        self._model: SingleTaskGP | None = None
        self._model_n = -1
        # fit_mode="warm": the last anchor's size and fitted raw hyperparameters
        self._anchor: tuple[int, dict[str, torch.Tensor]] | None = None

    def use_prior(self, prior: Any, mode: str, top_k: int) -> None:
        """Lean on ``prior`` (``PriorData``): "warmstart" or "multitask" (see the class)."""
        prior.check_dim(self.dim)
        self.prior, self.prior_mode, self.prior_top_k = prior, mode, int(top_k)
        if mode == "multitask":
            self.n_initial = max(int(top_k), 1)
            self._model = None

    @property
    def multitask(self) -> bool:
        """Whether the model is the multitask GP over prior and own data."""
        return self.prior is not None and self.prior_mode == "multitask"

    @property
    def _min_observed(self) -> int:
        """Own observations the model needs (the multitask GP has the prior's besides)."""
        return 1 if self.multitask else 2

    def _default_step(self, index: int) -> str:
        if index < self.n_initial or self.n_observed < self._min_observed:
            return "design"
        return "model"

    def _task_correlation(self, steps: list[str]) -> float | None:
        if not self.multitask or "model" not in steps:
            return None
        return task_correlation(self.model())

    # --- representation -----------------------------------------------------------------------
    @property
    def _use_levels(self) -> bool:
        return self.settings.space == "levels"

    def _grid(self) -> tuple[Policy, np.ndarray]:
        """The policy and the number of values of each of its grid coordinates."""
        assert self.policy is not None
        return self.policy, np.asarray(self.policy.grid_sizes())

    def _features(self, theta: np.ndarray) -> np.ndarray:
        """(N, D) θ → the GP's inputs: θ, or the grid coordinates scaled to [0, 1]."""
        if not self._use_levels:
            return np.atleast_2d(theta)
        policy, sizes = self._grid()
        return policy.grid_from_theta(theta) / np.maximum(sizes - 1, 1)

    def _theta_of_features(self, feats: np.ndarray) -> np.ndarray:
        """(N, F) features on the grid → (N, D) θ at the centres of their bins."""
        policy, sizes = self._grid()
        scale = np.maximum(sizes - 1, 1)
        return policy.theta_from_grid(np.rint(np.clip(np.atleast_2d(feats), 0, 1) * scale))

    # --- model --------------------------------------------------------------------------------
    def _on_observe(self) -> None:
        self._model = None

    def _train_tensors(
        self, n: int | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """(N, F) inputs, (N, 1) outcomes and (N, 1) noise variances or None, of the first ``n``
        observations (all by default); the same tensors the model at ``n`` observations saw."""
        x, y, sem = self.train_data()
        if n is not None:
            x, y, sem = x[:n], y[:n], (None if sem is None else sem[:n])
            if sem is not None and not np.isfinite(sem).any():
                sem = None
        tx = torch.as_tensor(self._features(x), dtype=DTYPE)
        ty = torch.as_tensor(y, dtype=DTYPE).unsqueeze(-1)
        if sem is None:
            return tx, ty, None
        known = sem[np.isfinite(sem)]
        # Observations without an SEM get the median known one; none may be exactly noise-free.
        filled = np.where(np.isfinite(sem), sem, np.median(known))
        floor = 1e-6 * max(float(np.var(y)), 1e-12)
        yvar = np.maximum(filled**2, floor)
        return tx, ty, torch.as_tensor(yvar, dtype=DTYPE).unsqueeze(-1)

    def _extra_noise(self, n: int) -> torch.Tensor | None:
        """(n,) age noise of the first ``n`` observations, or None (not weighed by age)."""
        h = self.settings.age_halflife_trials
        if h is None:
            return None
        return torch.as_tensor(age_noise(n, h), dtype=DTYPE)

    def _fit(
        self, n: int, start: dict[str, torch.Tensor] | None = None
    ) -> SingleTaskGP | MultiTaskGP:
        """The GP of the first ``n`` observations, fitted from the priors' defaults or, with
        ``start``, from those hyperparameters (raw parameter name → tensor)."""
        tx, ty, tyvar = self._train_tensors(n)
        with _TORCH_RNG_LOCK, torch.random.fork_rng():
            torch.manual_seed(call_seed(self.seed, n, 0, salt=1))
            if self.multitask:
                px = torch.as_tensor(self._features(np.array(self.prior.theta)), dtype=DTYPE)
                py = torch.as_tensor(np.array(self.prior.objective), dtype=DTYPE).unsqueeze(-1)
                mt = build_multitask_gp(
                    px, py, tx, ty, self.settings.model_preset, self._extra_noise(n)
                )
                return fit_gp(mt, self.settings.fit_maxiter or MULTITASK_FIT_MAXITER)
            gp = build_gp(tx, ty, tyvar, self.settings.model_preset, self._extra_noise(n))
            maxiter = self.settings.fit_maxiter
            if start is not None:
                gp.load_state_dict(start, strict=False)
                if self.settings.warm_maxiter == 0:  # the anchor's hyperparameters, as they are
                    return gp.eval()
                maxiter = min(maxiter or self.settings.warm_maxiter, self.settings.warm_maxiter)
            return fit_gp(gp, maxiter)

    def model(self) -> SingleTaskGP | MultiTaskGP:
        """The GP fitted to all observations so far (refit after any new observation).

        ``fit_mode="full"`` (the paper) fits every GP from the priors' defaults.
        ``fit_mode="warm"`` fits from scratch only at anchor sizes (``anchor_size``) and starts
        every other fit from the last anchor's hyperparameters, a few L-BFGS-B steps instead of
        about a hundred at N = 500. Either way the model is a function of the data alone, so a
        rebuilt optimiser agrees with a live one (a rebuilt one pays for its anchor fit once).
        """
        if self.n_observed < self._min_observed:
            raise SettingsError(f"the GP needs at least {self._min_observed} observations")
        n = self.n_observed
        if self._model is not None and self._model_n == n:
            return self._model
        s = self.settings
        if s.fit_mode == "full" or self.multitask:
            self._model = self._fit(n)
        else:
            a = anchor_size(n, s.refit_every, s.refit_fraction)
            if a == n:
                self._model = self._fit(n)
                self._anchor = (n, _raw_hyperparameters(self._model))
            else:
                if self._anchor is None or self._anchor[0] != a:
                    self._anchor = (a, _raw_hyperparameters(self._fit(a)))
                self._model = self._fit(n, start=self._anchor[1])
        self._model_n = n
        assert self._model is not None
        return self._model

    def predict(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean (n,) and std (n,) of J at θ (n, dim), in objective units."""
        th = self._check_theta(theta)
        x = torch.as_tensor(self._features(th), dtype=DTYPE)
        model = self.model()
        with torch.no_grad():
            post = model.posterior(x)
            mean = post.mean.squeeze(-1).numpy().copy()
            std = post.variance.clamp_min(0).sqrt().squeeze(-1).numpy().copy()
        return mean, std

    def feature_lengthscales(self) -> np.ndarray:
        """(F,) fitted lengthscales of the GP's inputs (θ dims, or level features)."""
        covar = self.model().covar_module
        if self.multitask:
            covar = covar.kernels[0]  # the input kernel (the other one is the task kernel)
        kernel = getattr(covar, "base_kernel", covar)
        return kernel.lengthscale.detach().reshape(-1).numpy().copy()

    def lengthscales(self) -> np.ndarray:
        """(dim,) fitted lengthscale per θ dimension (levels space: the shortest of its step)."""
        ls = self.feature_lengthscales()
        if not self._use_levels:
            return ls
        h = self.settings.horizon
        per_step = ls[: h * N_PAIRED].reshape(h, N_PAIRED).min(axis=1)
        return np.concatenate([per_step, ls[h * N_PAIRED :]])

    def search_bounds(self) -> torch.Tensor:
        """(2, dim) box the acquisition is optimised in: the unit box, or the trust region."""
        if not self.settings.trust_region:
            return _unit_bounds(self.dim)
        x, y, _ = self.train_data()
        state = trust_region_state(y, self.n_initial, self.dim)
        centre = x[int(np.argmax(y))]
        ls = self.feature_lengthscales()
        weights = ls / np.exp(np.mean(np.log(ls)))  # geometric mean 1
        half = 0.5 * state.length * weights
        lo, hi = np.clip(centre - half, 0.0, 1.0), np.clip(centre + half, 0.0, 1.0)
        return torch.as_tensor(np.stack([lo, hi]), dtype=DTYPE)

    # --- asking --------------------------------------------------------------------------------
    def _initial_points(self, start: int, count: int) -> np.ndarray:
        """Points ``start .. start+count`` of this seed's initial design, (count, dim)."""
        s = self.settings
        if s.initial_design == "sobol" and not self._use_levels:
            engine = torch.quasirandom.SobolEngine(self.dim, scramble=True, seed=self.seed)
            return engine.draw(start + count, dtype=DTYPE)[start:].numpy()
        policy, sizes = self._grid()
        engine = torch.quasirandom.SobolEngine(len(sizes), scramble=True, seed=self.seed)
        u = engine.draw(start + count, dtype=DTYPE)[start:].numpy()
        if s.initial_design == "corners":
            rng = np.random.default_rng([self.seed & 0xFFFFFFFF, 7, start, count])
            flip = rng.random(u.shape) < s.corner_prob
            u = np.where(flip, np.rint(rng.random(u.shape)), u)
        return policy.theta_from_grid(np.floor(u * sizes).clip(0, sizes - 1))

    def _keys(self, theta: np.ndarray) -> list[tuple[Any, ...]]:
        """Identity of each θ row: its schedule when the levels are known, else θ itself."""
        if self.policy is not None:
            return [tuple(row) for row in self.policy.grid_from_theta(theta).tolist()]
        return [tuple(np.round(row, 12).tolist()) for row in np.atleast_2d(theta)]

    def _design_points(self, start: int, count: int, pending: np.ndarray) -> np.ndarray:
        """Design points ``start ..`` (count, dim), each replaced by the next one of the
        sequence when it is already observed, pending or picked (an abandoned design trial
        shifts the count, so point ``start`` may be one still pending)."""
        pts = self._initial_points(start, count)
        taken = set(self._keys(self.train_data()[0]))
        if len(pending):
            taken.update(self._keys(pending))
        nxt = start + count
        for i, key in enumerate(self._keys(pts)):
            while key in taken and nxt < start + count + 10_000:
                pts[i] = self._initial_points(nxt, 1)[0]
                key, nxt = self._keys(pts[i])[0], nxt + 1
            taken.add(key)
        return pts

    def _suggest(self, n: int, pending: np.ndarray) -> np.ndarray:
        start = self.n_observed + len(pending)
        n_init = max(0, min(n, self.n_initial - start))
        if self.n_observed < self._min_observed:
            n_init = n
        out = [self._design_points(start, n_init, pending)] if n_init else []
        if n_init < n:
            pend = np.concatenate([pending, *out]) if out else pending
            out.append(self._acquire(n - n_init, pend))
        return np.concatenate(out)

    def _acquisition(self, model: SingleTaskGP, pending: torch.Tensor | None, q: int, seed: int):
        s = self.settings
        _, y, sem = self.train_data()
        tx, _, _ = self._train_tensors()
        batch = pending is not None or q > 1
        sampler = SobolQMCNormalSampler(torch.Size([s.mc_samples]), seed=seed)
        acq: AcquisitionFunction
        exact = None
        if s.acq_posterior == "cached" and not batch:
            exact = ExactPosterior.of(model)
        if s.acquisition == "ucb":
            if batch:
                acq = qUpperConfidenceBound(model, beta=s.kappa, sampler=sampler, X_pending=pending)
            elif exact is not None:
                acq = CachedUCB(model, beta=s.kappa, exact=exact)
            else:
                acq = UpperConfidenceBound(model, beta=s.kappa)
        elif s.acquisition == "qlognei" or batch or sem is not None:
            acq = qLogNoisyExpectedImprovement(
                model, X_baseline=tx, sampler=sampler, X_pending=pending, prune_baseline=True
            )
        elif exact is not None:
            acq = CachedLogEI(model, best_f=float(y.max()), exact=exact)
        else:
            acq = LogExpectedImprovement(model, best_f=float(y.max()))
        return acq

    def _grid_search(
        self, acq: AcquisitionFunction, q: int, x_seen: torch.Tensor, rng: np.random.Generator
    ) -> np.ndarray:
        """Maximise ``acq`` over the level grid: (q, F) features, none of them already seen.

        BoTorch's ``optimize_acqf_discrete_local_search``: from each start, best-improvement
        moves of one grid coordinate until a local optimum; for q > 1 greedily, each pick
        pending for the next and avoided. The first pick starts from the best
        ``num_restarts`` of ``raw_samples`` random grid points plus mutants of the best
        observations (the acquisition's peaks are often near them).
        """
        s = self.settings
        _, sizes = self._grid()  # grid points per feature
        scale = np.maximum(sizes - 1, 1)
        seen_x = x_seen.numpy()
        seen = {tuple(r) for r in np.rint(seen_x * scale).astype(np.int64).tolist()}
        _, y, _ = self.train_data()
        top = np.rint(seen_x[: len(y)][np.argsort(-y)[:5]] * scale).astype(np.int64)
        pool = [rng.integers(0, sizes, size=(s.raw_samples, len(sizes)))]
        for base in top:
            mut = np.repeat(base[None], 64, axis=0)
            for row in mut:
                k = rng.integers(1, 4)
                j = rng.choice(len(sizes), size=k, replace=False)
                row[j] = rng.integers(0, sizes[j])
            pool.append(mut)
        cand = np.unique(np.concatenate(pool), axis=0)
        cand = torch.as_tensor(cand[[tuple(r) not in seen for r in cand.tolist()]] / scale)
        with torch.no_grad():
            xs = cand.unsqueeze(-2)
            vals = torch.cat([acq(xs[i : i + 1024]) for i in range(0, len(xs), 1024)]).numpy()
        starts = cand[np.argsort(-vals)[: s.num_restarts]].unsqueeze(-2)
        picks, _ = optimize_acqf_discrete_local_search(
            acq,
            discrete_choices=[torch.arange(n, dtype=DTYPE) / max(n - 1, 1) for n in sizes],
            q=q,
            num_restarts=s.num_restarts,
            raw_samples=s.raw_samples,
            X_avoid=x_seen,
            batch_initial_conditions=starts,
            return_acq_values=False,
        )
        return picks.numpy()

    def _acquire(self, q: int, pending: np.ndarray) -> np.ndarray:
        s = self.settings
        seed = call_seed(self.seed, self.n_observed, len(pending))
        model = self.model()
        pend = torch.as_tensor(self._features(pending), dtype=DTYPE) if len(pending) else None
        with _TORCH_RNG_LOCK, torch.random.fork_rng():
            torch.manual_seed(seed)
            acq = self._acquisition(model, pend, q, seed)
            if self._use_levels:
                x_seen = self._train_tensors()[0]
                if pend is not None:
                    x_seen = torch.cat([x_seen, pend])
                cand = self._grid_search(acq, q, x_seen, np.random.default_rng(seed))
                return self._theta_of_features(cand)
            if s.distinct:
                seen = self.train_data()[0]
                if len(pending):
                    seen = np.concatenate([seen, pending])
                return self._distinct_search(acq, q, seed, seen)
            cand, _ = optimize_acqf(
                acq,
                bounds=self.search_bounds(),
                q=q,
                num_restarts=s.num_restarts,
                raw_samples=s.raw_samples,
                sequential=q > 1,
                options={"seed": seed},
            )
        return cand.detach().numpy()

    def _distinct_search(
        self, acq: AcquisitionFunction, q: int, seed: int, seen_theta: np.ndarray
    ) -> np.ndarray:
        """(q, dim) maximisers of ``acq``, each with a schedule not in ``seen_theta`` (N, dim)
        nor picked before it; picks after the first are pending for the next (MC acqs)."""
        from botorch.utils.sampling import draw_sobol_samples

        s = self.settings
        bounds = self.search_bounds()
        seen = set(self._keys(seen_theta))
        picks: list[np.ndarray] = []
        for k in range(q):
            cands, vals = optimize_acqf(
                acq,
                bounds=bounds,
                q=1,
                num_restarts=s.num_restarts,
                raw_samples=s.raw_samples,
                return_best_only=False,
                options={"seed": seed + k},
            )
            pool, pool_vals = cands.detach().reshape(-1, self.dim), vals.detach().reshape(-1)
            chosen = self._best_new(pool, pool_vals, seen)
            if chosen is None:  # every local optimum is a schedule already run or pending
                raw = draw_sobol_samples(bounds, n=s.raw_samples, q=1, seed=seed + k)
                with torch.no_grad():
                    raw_vals = acq(raw)
                chosen = self._best_new(raw.reshape(-1, self.dim), raw_vals.reshape(-1), seen)
            if chosen is None:
                raise SettingsError("no schedule left that was not already observed or pending")
            seen.update(self._keys(chosen[None]))
            picks.append(chosen)
            if k + 1 < q and hasattr(acq, "set_X_pending"):
                new = torch.as_tensor(chosen[None], dtype=DTYPE)
                prev = acq.X_pending
                acq.set_X_pending(new if prev is None else torch.cat([prev, new]))
        return np.stack(picks)

    def _best_new(
        self, x: torch.Tensor, vals: torch.Tensor, seen: set[tuple[int, ...]]
    ) -> np.ndarray | None:
        """The highest-valued row of ``x`` (n, dim) whose schedule key is not in ``seen``."""
        xs = x.numpy()
        keys = self._keys(xs)
        for i in torch.argsort(vals, descending=True).tolist():
            if keys[i] not in seen:
                return xs[i].copy()
        return None
