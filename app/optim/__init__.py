"""Ask/tell optimisers over the policy's unit box: BoTorch BO and the paper's baselines and peers.

opt = make_optimizer("bo-lei", dim=11, seed=0)
theta = opt.suggest(1)          # (1, 11) in [0, 1]
opt.observe(theta[0], 17.3)     # or observe_many([Observation(...), ...]) to rebuild
opt.suggestion_basis()          # what the last suggestion leaned on (prior, design, model)

A sim prior: ``make_optimizer(..., prior=PriorData(theta, objective), prior_mode=...)`` or
``OptimizerSpec(..., prior=...)``; see ``app.optim.prior``.

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
from app.optim.prior import PRIOR_MODES, PriorData, check_prior_settings

if TYPE_CHECKING:
    from app.optim.bo import BayesOpt


def make_optimizer(
    method: str, dim: int, *, seed: int, prior: PriorData | None = None, **settings: Any
) -> Optimizer:
    """Build an optimiser by name (one of ``METHODS``) for θ ∈ [0,1]^dim.

    ``prior``: another experiment's trials to lean on, as the settings ``prior_mode``
    ("multitask": BO methods only, their default; "warmstart": every method, the others'
    default) and ``prior_top_k`` (the prior's best θ that start the design, 2) say. Both
    settings are checked (and ignored) without a prior.

    Raises:
        SettingsError (a ValueError): unknown method, a bad setting, or a prior that does not
        fit (wrong D).
    """
    if method not in METHODS:
        raise SettingsError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    settings = dict(settings)
    prior_mode, prior_top_k = check_prior_settings(method, method in BO_METHODS, settings)
    if prior is not None and not isinstance(prior, PriorData):
        raise SettingsError(f"prior must be a PriorData, got {type(prior).__name__}")
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
    if prior is not None:
        opt.use_prior(prior, prior_mode, prior_top_k)
    return opt


def build_optimizer(spec: OptimizerSpec) -> Optimizer:
    """The optimiser ``spec`` describes (the one way the service and the benchmarks build one)."""
    return make_optimizer(spec.method, spec.dim, seed=spec.seed, prior=spec.prior, **spec.kwargs())


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
    "PRIOR_MODES",
    "BayesOpt",
    "Observation",
    "ObservationError",
    "OptimError",
    "Optimizer",
    "OptimizerSpec",
    "OptunaSampler",
    "PriorData",
    "RandomSearch",
    "SettingsError",
    "Surrogate",
    "build_optimizer",
    "make_optimizer",
]
