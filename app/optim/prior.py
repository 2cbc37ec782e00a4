"""A sim prior: another experiment's trials (typically the simulator's) on the same policy,
for an optimiser to lean on. Imports no torch.

    prior = PriorData(theta=sim_theta, objective=sim_scores)     # (N, D) in [0, 1], (N,)
    spec = OptimizerSpec("bo-lei-default", levels=5, horizon=10, with_release=True, seed=0,
                         settings={"prior_mode": "multitask"}, prior=prior)
    opt = build_optimizer(spec)

Two ways to use it (the setting ``prior_mode``):
  * ``"multitask"`` (BO methods only; their default): the GP is BoTorch's ``MultiTaskGP`` over
    (θ, source) with the prior as task 0 and the optimiser's own observations as task 1 (the
    target); the acquisition asks about task 1. The initial design shrinks to the prior's
    ``prior_top_k`` best θ.
  * ``"warmstart"`` (every method; the default of the non-BO ones): the initial design starts
    with the prior's ``prior_top_k`` best θ, then goes on as without a prior; the models see
    only the optimiser's own observations.

The θ are the optimisers' unit-box θ (``app.policy``), so a prior is only meaningful between
experiments with the same policy shape (P, H, release step) and limits; the service checks that.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.optim.base import SettingsError

PRIOR_MODES = ("multitask", "warmstart")
#: how many of the prior's best θ start the initial design, unless the setting says otherwise
DEFAULT_PRIOR_TOP_K = 2


@dataclass(frozen=True, eq=False)
class PriorData:
    """Prior trials: θ (N, D) in [0, 1] (the optimisers' unit box) and their objective (N,).

    Validated on construction (a ``SettingsError`` names what is wrong); stored as read-only
    float64 copies. Equal when their θ and objectives are equal.
    """

    theta: np.ndarray
    objective: np.ndarray
    #: a label for the operator ("sim experiment 12"); not used by the optimisers
    source: str = field(default="prior")

    def __post_init__(self) -> None:
        try:
            th = np.array(self.theta, dtype=np.float64)
            y = np.array(self.objective, dtype=np.float64)
        except (TypeError, ValueError):
            raise SettingsError("sim prior: theta and objective must be numbers") from None
        if th.ndim != 2 or th.shape[0] < 1 or th.shape[1] < 1:
            raise SettingsError(
                f"sim prior: theta must have shape (N, D) with N ≥ 1, got {th.shape}"
            )
        if y.shape != (th.shape[0],):
            raise SettingsError(
                f"sim prior: objective must have shape ({th.shape[0]},) (one per θ), got {y.shape}"
            )
        if not np.all(np.isfinite(th)):
            i = int(np.argwhere(~np.isfinite(th))[0][0])
            raise SettingsError(f"sim prior: θ of trial {i} is not finite")
        if np.any((th < 0.0) | (th > 1.0)):
            i, j = (int(v) for v in np.argwhere((th < 0.0) | (th > 1.0))[0])
            raise SettingsError(f"sim prior: θ[{i}][{j}] = {float(th[i, j])!r} is outside [0, 1]")
        if not np.all(np.isfinite(y)):
            i = int(np.argwhere(~np.isfinite(y))[0][0])
            raise SettingsError(
                f"sim prior: objective of trial {i} is not finite ({float(y[i])!r})"
            )
        th.setflags(write=False)
        y.setflags(write=False)
        object.__setattr__(self, "theta", th)
        object.__setattr__(self, "objective", y)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PriorData):
            return NotImplemented
        return np.array_equal(self.theta, other.theta) and np.array_equal(
            self.objective, other.objective
        )

    def __hash__(self) -> int:
        return hash((self.theta.tobytes(), self.objective.tobytes()))

    @property
    def n(self) -> int:
        """N, the number of prior trials."""
        return int(self.theta.shape[0])

    @property
    def dim(self) -> int:
        """D, the θ dimension."""
        return int(self.theta.shape[1])

    def check_dim(self, dim: int) -> None:
        """Raise a SettingsError unless the prior's θ have ``dim`` dimensions."""
        if self.dim != dim:
            raise SettingsError(
                f"sim prior: its θ have {self.dim} dimensions but this optimiser's have {dim} "
                "(the policy's horizon and release step must match)"
            )

    def best(self, k: int) -> np.ndarray:
        """(≤ k, D) the prior's best θ, best first, each θ once (ties: earlier trial first)."""
        order = np.argsort(-self.objective, kind="stable")
        out: list[np.ndarray] = []
        seen: set[bytes] = set()
        for i in order:
            key = np.round(self.theta[i], 12).tobytes()
            if key in seen:
                continue
            seen.add(key)
            out.append(self.theta[i])
            if len(out) == k:
                break
        return np.asarray(out, dtype=np.float64).reshape(-1, self.dim)


def check_prior_settings(method: str, is_bo: bool, settings: dict[str, Any]) -> tuple[str, int]:
    """Pop and check ``prior_mode`` and ``prior_top_k`` from ``settings`` (in place): the mode
    (default "multitask" for BO methods, "warmstart" for the others) and top-k (≥ 0)."""
    mode = settings.pop("prior_mode", None)
    top_k = settings.pop("prior_top_k", DEFAULT_PRIOR_TOP_K)
    if mode is None:
        mode = "multitask" if is_bo else "warmstart"
    if mode not in PRIOR_MODES:
        raise SettingsError(f"prior_mode must be one of {PRIOR_MODES}, got {mode!r}")
    if mode == "multitask" and not is_bo:
        raise SettingsError(
            f"prior_mode 'multitask' needs a BO method (a GP over θ and source); "
            f"{method} can use prior_mode 'warmstart'"
        )
    if isinstance(top_k, bool) or not isinstance(top_k, int | np.integer) or not 0 <= top_k <= 100:
        raise SettingsError(f"prior_top_k must be an integer in 0..100, got {top_k!r}")
    return str(mode), int(top_k)
