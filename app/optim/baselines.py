"""The paper's baselines (CEM, random search) and peers (Optuna TPE / GP, CMA-ES).

Each is a pure function of (seed, settings, observations in order, pending): state is rebuilt
by replaying the observations through a freshly seeded instance on every suggestion.
"""

from __future__ import annotations

import logging
import threading
import warnings
from typing import Any

import numpy as np

from app.optim.base import Optimizer, SettingsError, call_seed

#: CEM's initial standard deviation in the paper's runs: a uniform distribution's over the box,
#: 1/√12 (ROBOT.md: "initial variance wide enough to cover the whole box"). The reading that
#: reproduces the paper's CEM rows: with σ₀ = 1 (CEM's default here) the clipped samples pile up
#: on the box's faces, bang-bang schedules, and score far above the paper's (docs/bench/tables.md).
PAPER_CEM_INIT_STD = 12**-0.5
MAX_SETTING = 10_000  # a population, popsize or startup count beyond this is no sane setting


def _positive_int(name: str, value: Any, minimum: int = 1, maximum: int = MAX_SETTING) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | np.integer)
        or not minimum <= value <= maximum
    ):
        raise SettingsError(f"{name} must be an integer in {minimum}..{maximum}, got {value!r}")
    return int(value)


def _no_settings(method: str, settings: dict[str, Any]) -> None:
    if settings:
        raise SettingsError(f"{method} takes no setting(s) {', '.join(sorted(settings))}")


class RandomSearch(Optimizer):
    """Uniform samples on the box; point k is drawn from a generator seeded by (seed, k).

    Settings:
        population: candidates per generation (50; bookkeeping only: all are uniform).
    """

    method = "random"

    def __init__(self, dim: int, *, seed: int, population: int = 50) -> None:
        super().__init__(dim, seed=seed)
        self.population = _positive_int("population", population)

    def _default_step(self, index: int) -> str:
        return "design"  # every point is a uniform draw

    def _suggest(self, n: int, pending: np.ndarray) -> np.ndarray:
        start = self.n_observed + len(pending)
        return np.stack(
            [
                np.random.default_rng([self.seed & 0xFFFFFFFF, 0, k]).random(self.dim)
                for k in range(start, start + n)
            ]
        )


class CEM(Optimizer):
    """Cross-entropy method as in the paper: D + 1 uniform samples fix the initial mean, the
    initial standard deviation covers the box, populations of 50 are drawn from a diagonal
    Gaussian and clipped to the box, and the elite (top 20 %) sets the next mean and variance.

    Generation g holds observations ``n_init + g·population ... + population`` (in order).

    Settings:
        population (50), elite_frac (0.2), n_initial (D + 1), init_std (1.0: ±1σ spans the box
        from any mean), min_std (1e-6).
    """

    method = "cem"

    def __init__(
        self,
        dim: int,
        *,
        seed: int,
        population: int = 50,
        elite_frac: float = 0.2,
        n_initial: int | None = None,
        init_std: float = 1.0,
        min_std: float = 1e-6,
    ) -> None:
        super().__init__(dim, seed=seed)
        self.population = _positive_int("population", population, 2)
        if not 0.0 < float(elite_frac) <= 1.0:
            raise SettingsError(f"elite_frac must be in (0, 1], got {elite_frac!r}")
        self.n_elite = max(1, round(self.population * float(elite_frac)))
        self.n_initial = (
            self.dim + 1 if n_initial is None else _positive_int("n_initial", n_initial)
        )
        if not float(init_std) > 0:
            raise SettingsError(f"init_std must be > 0, got {init_std!r}")
        self.init_std = float(init_std)
        self.min_std = float(min_std)

    def elite_update(self, theta: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One generation's (pop, D) θ and (pop,) values → next (D,) mean and (D,) std."""
        order = np.argsort(-np.asarray(values), kind="stable")[: self.n_elite]
        elite = np.asarray(theta)[order]
        return elite.mean(axis=0), np.maximum(elite.std(axis=0), self.min_std)

    def distribution(self, n_observed: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
        """Sampling (mean (D,), std (D,), generation index) after the first ``n_observed``."""
        n = self.n_observed if n_observed is None else n_observed
        x, y, _ = self.train_data()
        if n < self.n_initial:
            return np.full(self.dim, 0.5), np.full(self.dim, self.init_std), -1
        mean = x[: self.n_initial].mean(axis=0)
        std = np.full(self.dim, self.init_std)
        g = 0
        while self.n_initial + (g + 1) * self.population <= n:
            lo = self.n_initial + g * self.population
            mean, std = self.elite_update(
                x[lo : lo + self.population], y[lo : lo + self.population]
            )
            g += 1
        return mean, std, g

    def _suggest(self, n: int, pending: np.ndarray) -> np.ndarray:
        out = []
        for k in range(self.n_observed + len(pending), self.n_observed + len(pending) + n):
            if k < self.n_initial:
                rng = np.random.default_rng([self.seed & 0xFFFFFFFF, 1, k])
                out.append(rng.random(self.dim))
                continue
            # The distribution of point k's generation, or the latest known one when that
            # generation's parents are still pending.
            mean, std, g_known = self.distribution()
            g = (k - self.n_initial) // self.population
            rng = np.random.default_rng([self.seed & 0xFFFFFFFF, 2, g, k, g_known])
            out.append(np.clip(mean + std * rng.standard_normal(self.dim), 0.0, 1.0))
        return np.stack(out)


_CMA_LOCK = threading.Lock()


class CMAES(Optimizer):
    """CMA-ES (``cma`` package) on the box with its bound transform; observations are told
    generation by generation (popsize each) as they arrive.

    Settings: sigma0 (0.3), popsize (cma's default 4 + ⌊3 ln D⌋).
    """

    method = "cmaes"

    def __init__(
        self, dim: int, *, seed: int, sigma0: float = 0.3, popsize: int | None = None
    ) -> None:
        super().__init__(dim, seed=seed)
        if not float(sigma0) > 0:
            raise SettingsError(f"sigma0 must be > 0, got {sigma0!r}")
        self.sigma0 = float(sigma0)
        self.popsize = (
            4 + int(3 * np.log(self.dim))
            if popsize is None
            else _positive_int("popsize", popsize, 2)
        )

    def _suggest(self, n: int, pending: np.ndarray) -> np.ndarray:
        import cma

        x, y, _ = self.train_data()
        lam = self.popsize
        with _CMA_LOCK:
            # cma draws from numpy's global generator; keep the caller's state intact.
            state = np.random.get_state()
            try:
                opts = {
                    "bounds": [0.0, 1.0],
                    "seed": (self.seed & 0x7FFFFFFF) + 1,
                    "popsize": lam,
                    "verbose": -9,
                    "verb_log": 0,
                    "verb_disp": 0,
                    "tolfun": 0,
                    "tolx": 0,
                    "tolfunhist": 0,
                    "tolstagnation": int(1e9),
                    "CMA_diagonal": False,
                }
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    es = cma.CMAEvolutionStrategy(np.full(self.dim, 0.5), self.sigma0, opts)
                    g = 0
                    while (g + 1) * lam <= len(y):
                        es.ask()
                        sl = slice(g * lam, (g + 1) * lam)
                        es.tell(list(x[sl]), list(-y[sl]))
                        g += 1
                    first = len(y) - g * lam + len(pending)
                    cands = es.ask(number=max(lam, first + n))
            finally:
                np.random.set_state(state)
        return np.clip(np.asarray(cands[first : first + n]), 0.0, 1.0)


class OptunaSampler(Optimizer):
    """An Optuna sampler (TPE or GP) rebuilt on each call: observations are added as finished
    trials, pending ones as running trials, then ``ask`` proposes. Seeded per call.

    Settings: n_startup_trials (the sampler's default); TPE also takes multivariate (True).
    """

    def __init__(self, dim: int, *, seed: int, sampler: str, **settings: Any) -> None:
        super().__init__(dim, seed=seed)
        if sampler not in ("tpe", "gp"):
            raise SettingsError(f"optuna sampler must be 'tpe' or 'gp', got {sampler!r}")
        self.sampler_name = sampler
        self.method = f"optuna-{sampler}"
        allowed = {"n_startup_trials"} | ({"multivariate"} if sampler == "tpe" else set())
        unknown = sorted(set(settings) - allowed)
        if unknown:
            raise SettingsError(f"{self.method} takes no setting(s) {', '.join(unknown)}")
        if "n_startup_trials" in settings:
            _positive_int("n_startup_trials", settings["n_startup_trials"])
        self.sampler_settings = settings

    def _make_sampler(self, seed: int):
        import optuna

        if self.sampler_name == "tpe":
            kw = {"multivariate": True, **self.sampler_settings}
            return optuna.samplers.TPESampler(seed=seed, constant_liar=True, **kw)
        return optuna.samplers.GPSampler(seed=seed, **self.sampler_settings)

    def _suggest(self, n: int, pending: np.ndarray) -> np.ndarray:
        import optuna

        optuna.logging.set_verbosity(logging.WARNING)
        names = [f"x{i}" for i in range(self.dim)]
        dists = {k: optuna.distributions.FloatDistribution(0.0, 1.0) for k in names}
        x, y, _ = self.train_data()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            study = optuna.create_study(
                direction="maximize",
                sampler=self._make_sampler(call_seed(self.seed, len(y), len(pending))),
            )
            study.add_trials(
                [
                    optuna.trial.create_trial(
                        params=dict(zip(names, map(float, xi), strict=True)),
                        distributions=dists,
                        value=float(yi),
                    )
                    for xi, yi in zip(x, y, strict=True)
                ]
            )
            for p in pending:
                study.enqueue_trial(dict(zip(names, map(float, p), strict=True)))
                study.ask(dists)  # running: TPE's constant liar sees it
            out = []
            for _ in range(n):
                trial = study.ask(dists)
                out.append([trial.params[k] for k in names])
        return np.asarray(out, dtype=np.float64)
