"""The ask/tell protocol every optimiser follows, its data type and its errors.

An optimiser's suggestion is a pure function of (seed, settings, observations in order,
pending points): the trial service rebuilds it from the database on every suggest, so nothing
may live only in memory. Per-call randomness is derived from the seed and the data sizes.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


class OptimError(Exception):
    """Base of this package's errors."""


class SettingsError(OptimError, ValueError):
    """An unknown method or a bad setting; the message names it."""


class ObservationError(OptimError, ValueError):
    """θ, a value or a standard error that the optimiser cannot accept."""


@dataclass(frozen=True)
class Observation:
    """One finished trial: θ (D,) in [0,1], its objective value, and optionally its SEM."""

    theta: tuple[float, ...]
    value: float
    sem: float | None = None


def call_seed(seed: int, n_observed: int, n_pending: int, salt: int = 0) -> int:
    """Per-call seed derived from the data sizes (never from hidden state), in [0, 2^31)."""
    ss = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, n_observed, n_pending, salt])
    return int(ss.generate_state(1, dtype=np.uint32)[0] >> 1)


class Optimizer(ABC):
    """Ask/tell over the unit box [0,1]^dim; subclasses implement ``_suggest``.

    Args:
        dim: D, the number of policy parameters.
        seed: the seed every call derives its randomness from.

    Attributes:
        method: the name ``make_optimizer`` built it under (one of ``METHODS``).
        n_initial: suggestions drawn from the initial design before any model is used
            (0: the method has no separate initial design).
    """

    method: str = ""
    n_initial: int = 0
    #: the prior's θ and objective (``app.optim.prior.PriorData``), set by ``use_prior``
    prior: Any = None
    prior_mode: str | None = None
    prior_top_k: int = 0

    def __init__(self, dim: int, *, seed: int) -> None:
        if isinstance(dim, bool) or not isinstance(dim, int | np.integer) or dim < 1:
            raise SettingsError(f"dim must be an integer ≥ 1, got {dim!r}")
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
            raise SettingsError(f"seed must be an integer, got {seed!r}")
        self.dim = int(dim)
        self.seed = int(seed)
        self._x: list[np.ndarray] = []
        self._y: list[float] = []
        self._sem: list[float | None] = []
        self._basis: dict[str, Any] = {}

    # --- prior ---------------------------------------------------------------------------------
    def use_prior(self, prior: Any, mode: str, top_k: int) -> None:
        """Lean on ``prior`` (a ``PriorData`` with this optimiser's D) in ``mode``: here
        "warmstart" (the first ``top_k`` suggestions are the prior's best θ); BO overrides it for
        "multitask". Called by ``make_optimizer`` before any observation."""
        prior.check_dim(self.dim)
        if mode != "warmstart":
            name = self.method or type(self).__name__
            raise SettingsError(f"{name} cannot use prior_mode {mode!r}")
        self.prior, self.prior_mode, self.prior_top_k = prior, mode, int(top_k)

    def _prior_points(self, start: int, n: int, pending: np.ndarray) -> np.ndarray:
        """Up to ``n`` of the prior's best θ for suggestion indices ``start ..`` (those below
        ``prior_top_k``), skipping any already observed or pending."""
        if self.prior is None or start >= self.prior_top_k:
            return np.zeros((0, self.dim))
        taken = [*self._x, *pending]
        out: list[np.ndarray] = []
        for th in self.prior.best(self.prior_top_k)[start:]:
            if len(out) == n:
                break
            if any(np.allclose(th, t, rtol=0, atol=1e-12) for t in taken):
                continue
            out.append(th)
        return np.asarray(out, dtype=np.float64).reshape(-1, self.dim)

    def suggestion_basis(self) -> dict[str, Any]:
        """What the last ``suggest`` leaned on (JSON-safe), for the operator:

        ``mode`` ("multitask", "warmstart" or None: no prior), ``n_prior`` (prior trials the
        suggestion used: its θ came from them or a model saw them), ``n_own`` (this
        optimiser's observations), ``steps`` (per suggested θ: "prior" (one of the prior's
        best θ), "design" (the initial design) or "model"), and ``task_correlation`` (the
        multitask GP's learned correlation between prior and own data, else None).
        Empty before the first ``suggest``.
        """
        return dict(self._basis)

    # --- data ---------------------------------------------------------------------------------
    @property
    def n_observed(self) -> int:
        """Number of observations so far."""
        return len(self._y)

    @property
    def observations(self) -> list[Observation]:
        """The observations in order (what ``observe_many`` rebuilds from)."""
        return [
            Observation(tuple(float(v) for v in x), y, s)
            for x, y, s in zip(self._x, self._y, self._sem, strict=True)
        ]

    def train_data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(N, D) θ, (N,) values, and (N,) SEMs or None when no observation carries one."""
        x = np.asarray(self._x, dtype=np.float64).reshape(-1, self.dim)
        y = np.asarray(self._y, dtype=np.float64)
        if all(s is None for s in self._sem):
            return x, y, None
        return x, y, np.asarray([np.nan if s is None else s for s in self._sem])

    def _check_theta(self, theta: np.ndarray | Sequence[float], what: str = "θ") -> np.ndarray:
        try:
            th = np.asarray(theta, dtype=np.float64)
        except (TypeError, ValueError):
            raise ObservationError(f"{what} must be numbers in [0, 1]") from None
        if th.ndim == 1:
            th = th[None, :]
        if th.ndim != 2 or th.shape[1] != self.dim:
            raise ObservationError(
                f"{what} must have shape ({self.dim},) or (k, {self.dim}), got {np.shape(theta)}"
            )
        if not np.all(np.isfinite(th)):
            raise ObservationError(f"{what} must be finite")
        if np.any((th < 0.0) | (th > 1.0)):
            i, j = (int(v) for v in np.argwhere((th < 0.0) | (th > 1.0))[0])
            raise ObservationError(f"{what}[{i}][{j}] = {th[i, j]!r} is outside [0, 1]")
        return th

    def observe(
        self,
        theta: np.ndarray | Sequence[float],
        value: float | Sequence[float] | np.ndarray,
        sem: float | Sequence[float | None] | np.ndarray | None = None,
    ) -> None:
        """Record θ (D,) or (k, D) with value(s) and optional standard error(s) ≥ 0."""
        th = self._check_theta(theta)
        k = th.shape[0]
        vals = np.atleast_1d(np.asarray(value, dtype=np.float64))
        if vals.shape != (k,):
            raise ObservationError(f"need {k} value(s) for {k} θ, got shape {vals.shape}")
        if not np.all(np.isfinite(vals)):
            raise ObservationError(f"values must be finite, got {vals.tolist()}")
        if sem is None:
            sems: list[float | None] = [None] * k
        else:
            raw = [sem] if np.ndim(sem) == 0 else list(sem)  # type: ignore[arg-type]
            if len(raw) != k:
                raise ObservationError(f"need {k} SEM(s) for {k} θ, got {len(raw)}")
            sems = []
            for s in raw:
                if s is None:
                    sems.append(None)
                    continue
                s = float(s)
                if not math.isfinite(s) or s < 0:
                    raise ObservationError(f"SEM must be a finite number ≥ 0, got {s!r}")
                sems.append(s)
        for i in range(k):
            self._x.append(th[i].copy())
            self._y.append(float(vals[i]))
            self._sem.append(sems[i])
        self._on_observe()

    def observe_many(self, observations: Iterable[Observation]) -> None:
        """Rebuild: record past observations in order (same result as observing one by one)."""
        obs = list(observations)
        if not obs:
            return
        self.observe(
            np.asarray([o.theta for o in obs], dtype=np.float64),
            [o.value for o in obs],
            [o.sem for o in obs],
        )

    def _on_observe(self) -> None:  # noqa: B027 (an optional hook, not abstract)
        """Hook: invalidate caches after new data."""

    # --- asking --------------------------------------------------------------------------------
    def suggest(
        self, n: int = 1, *, pending: np.ndarray | Sequence[Sequence[float]] | None = None
    ) -> np.ndarray:
        """Return (n, D) new θ in [0,1], given (k, D) pending θ (suggested, not yet observed)."""
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise SettingsError(f"n must be an integer ≥ 1, got {n!r}")
        if pending is None or len(pending) == 0:
            pend = np.zeros((0, self.dim))
        else:
            pend = self._check_theta(pending, "pending θ")
        start = self.n_observed + len(pend)
        warm = self._prior_points(start, int(n), pend)
        steps = ["prior"] * len(warm)
        if len(warm) < n:
            rest = np.asarray(
                self._suggest(int(n) - len(warm), np.concatenate([pend, warm])), dtype=np.float64
            ).reshape(int(n) - len(warm), self.dim)
            out = np.concatenate([warm, rest])
            steps += [self._default_step(start + len(warm) + i) for i in range(len(rest))]
        else:
            out = warm
        self._basis = {
            "mode": self.prior_mode if self.prior is not None else None,
            "n_prior": self._n_prior_used(steps),
            "n_own": self.n_observed,
            "steps": steps,
            "task_correlation": self._task_correlation(steps),
        }
        return np.clip(out.reshape(int(n), self.dim), 0.0, 1.0)

    def _default_step(self, index: int) -> str:
        """The step of a suggestion at index ``index`` when ``_suggest`` did not say."""
        return "design" if index < self.n_initial else "model"

    def _n_prior_used(self, steps: list[str]) -> int:
        if self.prior is None:
            return 0
        if self.prior_mode == "multitask" and "model" in steps:
            return self.prior.n
        return self.prior.n if "prior" in steps else 0

    def _task_correlation(self, steps: list[str]) -> float | None:
        """The multitask GP's learned prior↔own correlation (BO overrides it)."""
        return None

    @abstractmethod
    def _suggest(self, n: int, pending: np.ndarray) -> np.ndarray:
        """(n, D) new θ given the (k, D) pending θ (already checked)."""


class Surrogate(ABC):
    """An optimiser with a model of the objective that the service can ask (the dashboard's
    predictions and the GP insight). Needs at least 2 observations."""

    @abstractmethod
    def predict(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean (n,) and std (n,) of the objective at θ (n, dim), in its units."""

    @abstractmethod
    def lengthscales(self) -> np.ndarray:
        """(dim,) fitted lengthscale per θ dimension."""
