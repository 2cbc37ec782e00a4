"""Method names, the default method, and the one rule that turns a method and the policy's
shape into an optimiser's settings. Imports no torch (the service's schemas and the CLI read it).

    spec = OptimizerSpec("bo-levels", levels=5, horizon=10, with_release=True, seed=0)
    spec.dim        # 11
    spec.kwargs()   # the settings ``make_optimizer`` gets: {"levels": 5, "horizon": 10}
    app.optim.build_optimizer(spec)

A sim prior rides along as ``OptimizerSpec(..., prior=PriorData(theta, objective))`` with the
settings ``prior_mode`` ("multitask": BO only, the BO default; "warmstart": any method, the
others' default) and ``prior_top_k`` (2); see ``app.optim.prior``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from app.optim.prior import PriorData
from app.policy import policy_dim

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
#: methods whose settings need the policy's P (and H): ``OptimizerSpec.kwargs`` passes them
NEEDS_LEVELS = frozenset({"bo-levels", "bo-lei-distinct"})


def needs_levels(method: str, settings: Mapping[str, Any]) -> bool:
    """Whether BO ``method`` with the caller's ``settings`` works on the policy's level grid
    (so needs ``levels`` = P and ``horizon`` = H)."""
    if method not in BO_METHODS:
        return False
    merged = {**BO_METHODS[method], **settings}
    return (
        merged.get("space") == "levels"
        or merged.get("initial_design") == "corners"
        or bool(merged.get("distinct"))
    )


@dataclass(frozen=True)
class OptimizerSpec:
    """Everything an optimiser is built from: the method, the policy's shape (P, H, release
    step), the seed, and the caller's settings. ``n_initial``, ``acquisition`` and ``kappa``
    (None: the method's own) are the experiment's BO columns; other methods ignore them.
    ``prior``: data from another experiment (a sim prior) the optimiser leans on, as the
    settings' ``prior_mode`` says (see ``app.optim.prior``)."""

    method: str
    levels: int
    horizon: int
    with_release: bool
    seed: int
    settings: Mapping[str, Any] = field(default_factory=dict)
    n_initial: int | None = None
    acquisition: str | None = None
    kappa: float | None = None
    prior: PriorData | None = None

    @property
    def dim(self) -> int:
        """D: one θ per control step, plus the release step."""
        return policy_dim(self.horizon, self.with_release)

    def kwargs(self) -> dict[str, Any]:
        """The settings ``make_optimizer(method, dim, seed=seed, **kwargs)`` gets: the BO
        columns that are set, then the caller's settings, then P and H where the method's
        settings need them (unless the caller gave them)."""
        out: dict[str, Any] = {}
        if self.method in BO_METHODS:
            for name in ("acquisition", "kappa", "n_initial"):
                if getattr(self, name) is not None:
                    out[name] = getattr(self, name)
        out.update(self.settings)
        if needs_levels(self.method, out):
            out.setdefault("levels", self.levels)
            out.setdefault("horizon", self.horizon)
        return out
