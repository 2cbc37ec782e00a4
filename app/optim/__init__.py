"""Ask/tell optimisers over the policy's unit box: BoTorch BO and the paper's baselines and peers.

opt = make_optimizer("bo-lei", dim=11, seed=0)
theta = opt.suggest(1)          # (1, 11) in [0, 1]
opt.observe(theta[0], 17.3)     # or observe_many([Observation(...), ...]) to rebuild
"""

from __future__ import annotations

from typing import Any

from app.optim.base import (
    Observation,
    ObservationError,
    OptimError,
    Optimizer,
    SettingsError,
)
from app.optim.baselines import CEM, CMAES, OptunaSampler, RandomSearch
from app.optim.bo import BayesOpt

# BO variants: method name → fixed settings (a caller's settings may override them).
BO_METHODS: dict[str, dict[str, Any]] = {
    "bo-lei": {"acquisition": "logei", "model_preset": "paper"},
    "bo-ucb": {"acquisition": "ucb", "model_preset": "paper", "kappa": 0.9},
    "bo-lei-default": {"acquisition": "logei", "model_preset": "default"},
    # LogEI on today's default GP, searched in TuRBO-1's trust region around the best trial
    "bo-turbo": {"acquisition": "logei", "model_preset": "default", "trust_region": True},
    # bo-lei-default that never suggests a schedule already observed or pending (needs levels=P)
    "bo-lei-distinct": {"acquisition": "logei", "model_preset": "default", "distinct": True},
    # GP over the pressure levels, bang-bang-rich initial design, acquisition optimised on the
    # level grid, never an action sequence seen (needs levels=P)
    "bo-levels": {
        "acquisition": "logei",
        "model_preset": "default",
        "space": "levels",
        "initial_design": "corners",
        "raw_samples": 1024,
        "num_restarts": 4,
        "fit_maxiter": 75,
    },
}
#: the method a new experiment gets unless it names one (see docs/bench/optim.md)
DEFAULT_METHOD = "bo-lei-default"
BASELINE_METHODS = ("cem", "random", "optuna-tpe", "optuna-gp", "cmaes")
METHODS: tuple[str, ...] = (*BO_METHODS, *BASELINE_METHODS)
# Methods whose settings need the policy's P (levels=…); the benchmark passes it.
NEEDS_LEVELS = frozenset({"bo-levels", "bo-lei-distinct"})


def make_optimizer(method: str, dim: int, *, seed: int, **settings: Any) -> Optimizer:
    """Build an optimiser by name (one of ``METHODS``) for θ ∈ [0,1]^dim.

    Raises:
        SettingsError (a ValueError): unknown method or a bad setting.
    """
    if method not in METHODS:
        raise SettingsError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    try:
        if method in BO_METHODS:
            opt: Optimizer = BayesOpt(dim, seed=seed, **{**BO_METHODS[method], **settings})
        elif method == "cem":
            opt = CEM(dim, seed=seed, **settings)
        elif method == "random":
            opt = RandomSearch(dim, seed=seed, **settings)
        elif method == "cmaes":
            opt = CMAES(dim, seed=seed, **settings)
        else:
            opt = OptunaSampler(dim, seed=seed, sampler=method.split("-")[1], **settings)
    except TypeError as exc:  # an unexpected keyword: name it as a bad setting
        raise SettingsError(f"{method}: {exc}") from None
    opt.method = method
    return opt


__all__ = [
    "BO_METHODS",
    "CEM",
    "CMAES",
    "DEFAULT_METHOD",
    "METHODS",
    "NEEDS_LEVELS",
    "BayesOpt",
    "Observation",
    "ObservationError",
    "OptimError",
    "Optimizer",
    "OptunaSampler",
    "RandomSearch",
    "SettingsError",
    "make_optimizer",
]
