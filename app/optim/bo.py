"""Bayesian optimisation with BoTorch behind the ask/tell protocol.

The GP is rebuilt and refit (``fit_gpytorch_mll``) from all observations whenever a suggestion
or prediction needs it, so a rebuilt optimiser and a live one give the same answers.

Two search representations:
  * ``space="theta"`` (the paper): the GP models J(θ) on the unit box [0,1]^D directly.
  * ``space="levels"`` (handful's variant): each θ_i is decoded to the six paired-command levels
    of its action (``g``'s digits, each scaled to [0,1]) and the release step to [0,1], so the
    GP sees pressures rather than action indices; the acquisition is optimised over the level
    grid by discrete local search and the result is mapped back to the centre of its θ bin.
"""

from __future__ import annotations

import math
import os
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
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
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.transforms import Normalize, Standardize
from botorch.models.utils.gpytorch_modules import (
    get_gaussian_likelihood_with_gamma_prior,
    get_matern_kernel_with_gamma_prior,
)
from botorch.optim import optimize_acqf
from botorch.sampling import SobolQMCNormalSampler
from gpytorch.mlls import ExactMarginalLogLikelihood

from app.optim.base import Optimizer, SettingsError, call_seed

ACQUISITIONS = ("logei", "ucb", "qlognei")
MODEL_PRESETS = ("paper", "default")
SPACES = ("theta", "levels")
INITIAL_DESIGNS = ("sobol", "corners")
N_PAIRED = 6  # paired commands per action (see app.policy)

DTYPE = torch.float64
# Torch's RNG is process-global; fork it per call under a lock so threads cannot interleave.
_TORCH_RNG_LOCK = threading.Lock()
#: intra-op threads for GP fits and acquisition searches. These GPs are small (N ≤ ~1000), so
#: one thread is as fast as two on an idle machine and several times faster on a busy one
#: (N = 100, D = 11: 1.5 s with 1 thread vs 11-13 s with 2, at load average 9 on 2 cores).
#: Parallelism comes from running many optimisers/rollouts side by side instead.
TORCH_THREADS = max(1, int(os.environ.get("HANDFUL_TORCH_THREADS", "1")))


@contextmanager
def _torch_threads() -> Iterator[None]:
    """Run the enclosed torch work on ``TORCH_THREADS`` threads; restore the setting after."""
    before = torch.get_num_threads()
    if before == TORCH_THREADS:
        yield
        return
    torch.set_num_threads(TORCH_THREADS)
    try:
        yield
    finally:
        torch.set_num_threads(before)


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


#: integer settings and their sane ranges (beyond them a suggestion costs minutes or more)
SETTING_RANGES: dict[str, tuple[int, int]] = {
    "num_restarts": (1, 64),
    "raw_samples": (1, 8192),
    "mc_samples": (1, 4096),
    "horizon": (1, 100),
    "fit_maxiter": (1, 10_000),
    "n_initial": (2, 10_000),
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
    if not isinstance(s.trust_region, bool):
        raise SettingsError(f"trust_region must be true or false, got {s.trust_region!r}")
    if s.trust_region and s.space != "theta":
        raise SettingsError("trust_region needs space='theta'")
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


class LevelSpace:
    """θ (D,) ↔ features (F,) = per-step paired-command levels / (P−1), plus release / (H−1).

    Mirrors ``app.policy.Policy.actions_from_theta`` (C-order digits, first most significant).
    """

    def __init__(self, levels: int, horizon: int, with_release: bool) -> None:
        self.levels = levels
        self.horizon = horizon
        self.with_release = with_release
        self.n_actions = levels**N_PAIRED
        self.n_features = horizon * N_PAIRED + int(with_release)

    def to_features(self, theta: np.ndarray) -> np.ndarray:
        """(N, D) θ → (N, F) features on the level grid in [0,1]."""
        th = np.atleast_2d(theta)
        a = np.minimum(np.floor(th[:, : self.horizon] * self.n_actions), self.n_actions - 1)
        digits = np.stack(
            np.unravel_index(a.astype(np.int64), (self.levels,) * N_PAIRED), axis=-1
        )  # (N, H, 6)
        feats = digits.reshape(th.shape[0], -1) / (self.levels - 1)
        if self.with_release:
            r = np.minimum(np.floor(th[:, self.horizon] * self.horizon), self.horizon - 1)
            feats = np.concatenate([feats, (r / max(self.horizon - 1, 1))[:, None]], axis=1)
        return feats

    def keys(self, theta: np.ndarray) -> list[tuple[int, ...]]:
        """(N, D) θ → one key per row: its H action indices (and release step), the schedule
        ``Policy.decode`` gives. Equal keys ⇔ the same pressure schedule and release."""
        th = np.atleast_2d(theta)
        a = np.minimum(np.floor(th[:, : self.horizon] * self.n_actions), self.n_actions - 1)
        cols = [a.astype(np.int64)]
        if self.with_release:
            r = np.minimum(np.floor(th[:, self.horizon] * self.horizon), self.horizon - 1)
            cols.append(r.astype(np.int64)[:, None])
        return [tuple(int(v) for v in row) for row in np.concatenate(cols, axis=1)]

    def to_theta(self, feats: np.ndarray) -> np.ndarray:
        """(N, F) features (snapped to the grid) → (N, D) θ at the centres of their bins."""
        f = np.atleast_2d(feats)
        n = f.shape[0]
        digits = np.rint(np.clip(f[:, : self.horizon * N_PAIRED], 0, 1) * (self.levels - 1))
        digits = digits.astype(np.int64).reshape(n, self.horizon, N_PAIRED)
        a = np.ravel_multi_index(tuple(np.moveaxis(digits, -1, 0)), (self.levels,) * N_PAIRED)
        theta = (a + 0.5) / self.n_actions
        if self.with_release:
            r = np.rint(np.clip(f[:, -1], 0, 1) * max(self.horizon - 1, 1))
            theta = np.concatenate([theta, ((r + 0.5) / self.horizon)[:, None]], axis=1)
        return theta

    def choices(self) -> list[torch.Tensor]:
        """The grid values of each feature (for discrete local search)."""
        lv = torch.linspace(0, 1, self.levels, dtype=DTYPE)
        out = [lv] * (self.horizon * N_PAIRED)
        if self.with_release:
            out.append(torch.linspace(0, 1, self.horizon, dtype=DTYPE))
        return out


def build_gp(
    train_x: torch.Tensor,
    train_y: torch.Tensor,
    train_yvar: torch.Tensor | None,
    model_preset: str,
) -> SingleTaskGP:
    """A SingleTaskGP on (N, F) inputs in [0,1] and (N, 1) outcomes; not yet fitted.

    ``paper``: ARD Matérn-5/2 in a ScaleKernel with BoTorch's older Gamma priors
    (lengthscale Gamma(3, 6), outputscale Gamma(2, 0.15), noise Gamma(1.1, 0.05)).
    ``default``: today's SingleTaskGP default (RBF, dimension-scaled LogNormal priors).
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
    return SingleTaskGP(train_x, train_y, train_yvar, **kwargs)


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
        fit_gpytorch_mll(mll, **kwargs)
    model.eval()
    return model


def _unit_bounds(f: int) -> torch.Tensor:
    return torch.stack([torch.zeros(f, dtype=DTYPE), torch.ones(f, dtype=DTYPE)])


class BayesOpt(Optimizer):
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
        distinct: never suggest θ whose schedule (action indices and release step, see
            ``LevelSpace.keys``; needs ``levels``) was observed or is pending: the acquisition's
            best local optimum with a new schedule, else the best new one of its raw samples.
    """

    method = "bo"

    def __init__(self, dim: int, *, seed: int, **settings: Any) -> None:
        super().__init__(dim, seed=seed)
        self.settings = _check_settings(self.dim, settings)
        s = self.settings
        self.n_initial = s.n_initial if s.n_initial is not None else self.dim + 1
        self.space: LevelSpace | None = None
        if s.space == "levels" or s.initial_design == "corners" or s.distinct:
            self.space = LevelSpace(s.levels or 2, s.horizon, self.dim == s.horizon + 1)
        self._model: SingleTaskGP | None = None
        self._model_n = -1

    # --- representation -----------------------------------------------------------------------
    @property
    def _use_levels(self) -> bool:
        return self.settings.space == "levels"

    def _features(self, theta: np.ndarray) -> np.ndarray:
        if self._use_levels:
            assert self.space is not None
            return self.space.to_features(theta)
        return np.atleast_2d(theta)

    # --- model --------------------------------------------------------------------------------
    def _on_observe(self) -> None:
        self._model = None

    def _train_tensors(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        x, y, sem = self.train_data()
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

    def model(self) -> SingleTaskGP:
        """The GP fitted to all observations so far (refit after any new observation)."""
        if self.n_observed < 2:
            raise SettingsError("the GP needs at least 2 observations")
        if self._model is None or self._model_n != self.n_observed:
            tx, ty, tyvar = self._train_tensors()
            with _TORCH_RNG_LOCK, _torch_threads(), torch.random.fork_rng():
                torch.manual_seed(call_seed(self.seed, self.n_observed, 0, salt=1))
                self._model = fit_gp(
                    build_gp(tx, ty, tyvar, self.settings.model_preset),
                    self.settings.fit_maxiter,
                )
            self._model_n = self.n_observed
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
        assert self.space is not None
        f = self.space.n_features
        engine = torch.quasirandom.SobolEngine(f, scramble=True, seed=self.seed)
        u = engine.draw(start + count, dtype=DTYPE)[start:].numpy()
        if s.initial_design == "corners":
            rng = np.random.default_rng([self.seed & 0xFFFFFFFF, 7, start, count])
            flip = rng.random(u.shape) < s.corner_prob
            u = np.where(flip, np.rint(rng.random(u.shape)), u)
        n_level_feats = self.space.horizon * N_PAIRED
        levels = np.floor(u[:, :n_level_feats] * self.space.levels).clip(0, self.space.levels - 1)
        u[:, :n_level_feats] = levels / (self.space.levels - 1)
        if self.space.with_release:
            h = self.space.horizon
            u[:, -1] = np.floor(u[:, -1] * h).clip(0, h - 1) / max(h - 1, 1)
        return self.space.to_theta(u)

    def _keys(self, theta: np.ndarray) -> list[tuple[Any, ...]]:
        """Identity of each θ row: its schedule when the levels are known, else θ itself."""
        if self.space is not None:
            return list(self.space.keys(theta))
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
        if self.n_observed < 2:
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
        if s.acquisition == "ucb":
            if batch:
                acq = qUpperConfidenceBound(model, beta=s.kappa, sampler=sampler, X_pending=pending)
            else:
                acq = UpperConfidenceBound(model, beta=s.kappa)
        elif s.acquisition == "qlognei" or batch or sem is not None:
            acq = qLogNoisyExpectedImprovement(
                model, X_baseline=tx, sampler=sampler, X_pending=pending, prune_baseline=True
            )
        else:
            acq = LogExpectedImprovement(model, best_f=float(y.max()))
        return acq

    def _grid_search(
        self, acq: AcquisitionFunction, q: int, x_seen: torch.Tensor, rng: np.random.Generator
    ) -> np.ndarray:
        """Maximise ``acq`` over the level grid: (q, F) features, none of them already seen.

        Scores ``raw_samples`` random grid points plus mutants of the best observations,
        then hill-climbs from the best ``num_restarts`` over single-feature changes. For q > 1,
        picks greedily, each pick becoming pending for the next (MC acquisitions).
        """
        assert self.space is not None
        s = self.settings
        sp = self.space
        sizes = np.array([len(c) for c in sp.choices()])  # grid points per feature
        scale = np.maximum(sizes - 1, 1)

        def to_x(idx: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(idx / scale, dtype=DTYPE)

        def score(idx: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                xs = to_x(idx).unsqueeze(-2)
                vals = [acq(xs[i : i + 1024]) for i in range(0, len(xs), 1024)]
            return torch.cat(vals).numpy()

        seen = {tuple(r) for r in np.rint(x_seen.numpy() * scale).astype(np.int64)}
        _, y, _ = self.train_data()
        top = np.rint(x_seen.numpy()[: len(y)][np.argsort(-y)[:5]] * scale).astype(np.int64)
        picks: list[np.ndarray] = []
        for _ in range(q):
            pool = [rng.integers(0, sizes, size=(s.raw_samples, len(sizes)))]
            for base in top:
                mut = np.repeat(base[None], 64, axis=0)
                for row in mut:
                    k = rng.integers(1, 4)
                    j = rng.choice(len(sizes), size=k, replace=False)
                    row[j] = rng.integers(0, sizes[j])
                pool.append(mut)
            cand = np.unique(np.concatenate(pool), axis=0)
            cand = cand[[tuple(r) not in seen for r in cand]]
            vals = score(cand)
            order = np.argsort(-vals)[: s.num_restarts]
            starts, start_vals = cand[order], vals[order]
            for _round in range(20):
                moved = False
                for i in range(len(starts)):
                    nb = np.repeat(starts[i][None], int(sizes.sum()), axis=0)
                    feat = np.repeat(np.arange(len(sizes)), sizes)
                    lvl = np.concatenate([np.arange(n) for n in sizes])
                    nb[np.arange(len(nb)), feat] = lvl
                    keep = [(tuple(r) not in seen) and (r != starts[i]).any() for r in nb]
                    nb = nb[keep]
                    if not len(nb):
                        continue
                    v = score(nb)
                    j = int(np.argmax(v))
                    if v[j] > start_vals[i]:
                        starts[i], start_vals[i], moved = nb[j], v[j], True
                if not moved:
                    break
            best = starts[int(np.argmax(start_vals))]
            picks.append(best)
            seen.add(tuple(best))
            if q > 1 and hasattr(acq, "set_X_pending"):
                prev = acq.X_pending
                new = to_x(best[None])
                acq.set_X_pending(new if prev is None else torch.cat([prev, new]))
        return np.stack(picks) / scale

    def _acquire(self, q: int, pending: np.ndarray) -> np.ndarray:
        s = self.settings
        seed = call_seed(self.seed, self.n_observed, len(pending))
        model = self.model()
        pend = torch.as_tensor(self._features(pending), dtype=DTYPE) if len(pending) else None
        with _TORCH_RNG_LOCK, _torch_threads(), torch.random.fork_rng():
            torch.manual_seed(seed)
            acq = self._acquisition(model, pend, q, seed)
            if self._use_levels:
                assert self.space is not None
                x_seen = self._train_tensors()[0]
                if pend is not None:
                    x_seen = torch.cat([x_seen, pend])
                cand = self._grid_search(acq, q, x_seen, np.random.default_rng(seed))
                return self.space.to_theta(cand)
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

        assert self.space is not None
        s = self.settings
        bounds = self.search_bounds()
        seen = set(self.space.keys(seen_theta))
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
            seen.update(self.space.keys(chosen[None]))
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
        assert self.space is not None
        xs = x.numpy()
        keys = self.space.keys(xs)
        for i in torch.argsort(vals, descending=True).tolist():
            if keys[i] not in seen:
                return xs[i].copy()
        return None
