"""Ask/tell optimisers over the policy's unit box: BoTorch BO and the paper's baselines and peers.

opt = make_optimizer("bo-lei", dim=11, seed=0)
theta = opt.suggest(1)          # (1, 11) in [0, 1]
opt.observe(theta[0], 17.3)     # or observe_many([Observation(...), ...]) to rebuild

Importing this package loads no torch: BoTorch is imported when a BO optimiser is built.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from app.optim.base import (
    Observation,
    ObservationError,
    OptimError,
    Optimizer,
    SettingsError,
    Surrogate,
)
from app.optim.baselines import CEM, CMAES, OptunaSampler, RandomSearch
from app.optim.methods import (
    BASELINE_METHODS,
    BO_METHODS,
    DEFAULT_METHOD,
    METHODS,
    NEEDS_LEVELS,
    OptimizerSpec,
)

if TYPE_CHECKING:
    from app.optim.bo import BayesOpt


def make_optimizer(method: str, dim: int, *, seed: int, **settings: Any) -> Optimizer:
    """Build an optimiser by name (one of ``METHODS``) for θ ∈ [0,1]^dim.

    Raises:
        SettingsError (a ValueError): unknown method or a bad setting.
    """
    if method not in METHODS:
        raise SettingsError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    try:
        if method in BO_METHODS:
            from app.optim.bo import BayesOpt

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


def build_optimizer(spec: OptimizerSpec) -> Optimizer:
    """The optimiser ``spec`` describes (the one way the service and the benchmarks build one)."""
    return make_optimizer(spec.method, spec.dim, seed=spec.seed, **spec.kwargs())


def __getattr__(name: str) -> Any:
    if name == "BayesOpt":  # loads torch and BoTorch
        from app.optim.bo import BayesOpt

        return BayesOpt
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "BASELINE_METHODS",
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
    "OptimizerSpec",
    "OptunaSampler",
    "RandomSearch",
    "SettingsError",
    "Surrogate",
    "build_optimizer",
    "make_optimizer",
]
