"""The paper's few-parameter policy: θ ∈ [0,1]^D → discrete paired actions → pressure schedule.

Chamber order everywhere: joint 0 (x+, x−, y+, y−), joint 1 (…), joint 2 (…): 12 pressures, Pa.
The six *paired commands* are, in order: j0.x, j0.y, j1.x, j1.y, j2.x, j2.y. Paired command u
sets the "+" chamber of its pair; the "−" chamber gets the mirrored pressure.

Action indices enumerate the P^6 level combinations in C order (``numpy.unravel_index``):
the first paired command (j0.x) is the most significant digit.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

import numpy as np
import numpy.typing as npt

N_CHAMBERS = 12
N_PAIRED = 6
#: 275,800 Pa: every chamber's command range is [0, 275.8 kPa] (ROBOT.md: 40 psi, as the
#: published simulator writes it; its reference runs in tests/sim/data command exactly 275,800)
SIM_MAX_PRESSURE_PA = 275_800.0
HORIZON = 10
EPISODE_S = 5.0
#: the tasks (ROBOT.md); throwing alone has a release step
TaskName = Literal["throw", "hammer", "tip_speed"]
TASKS: tuple[str, ...] = get_args(TaskName)
RELEASE_TASKS = frozenset({"throw"})
#: how each schedule row is applied over its control step: held, or ramped from the previous
#: row (from zero pressures at the start); ``app.sim.rollout`` says exactly
CommandHold = Literal["zero", "linear"]
COMMAND_HOLDS: tuple[str, ...] = get_args(CommandHold)
#: how the simulator scores an episode: the paper's formulas as printed, or what the published
#: simulator's code computes (``app.sim.rollout`` says exactly)
ObjectiveRule = Literal["paper", "published"]
OBJECTIVE_RULES: tuple[str, ...] = get_args(ObjectiveRule)
# The simulator settings that reproduce the paper's tables, chosen by measurement against the
# published simulator's random-search anchor (docs/bench/paper.md): commands ramped over each
# step, the published code's scoring, and the fast physics preset (its welded cube matched the
# anchor's per-θ scores as well as the reference preset's friction grasp, at a tenth the cost).
PAPER_PRESET = "fast"
PAPER_COMMAND_HOLD = "linear"
PAPER_OBJECTIVE_RULE = "published"

CHAMBER_NAMES: tuple[str, ...] = tuple(
    f"j{j}.{axis}{sign}" for j in range(3) for axis in ("x", "y") for sign in ("+", "-")
)
PAIRED_NAMES: tuple[str, ...] = tuple(f"j{j}.{axis}" for j in range(3) for axis in ("x", "y"))


def check_command_hold(command_hold: object) -> str:
    """``command_hold`` if known; ValueError naming the choices otherwise."""
    if command_hold not in COMMAND_HOLDS:
        raise ValueError(
            f"unknown command hold {command_hold!r}; choose one of {', '.join(COMMAND_HOLDS)}"
        )
    return str(command_hold)


def check_objective_rule(objective_rule: object) -> str:
    """``objective_rule`` if known; ValueError naming the choices otherwise."""
    if objective_rule not in OBJECTIVE_RULES:
        raise ValueError(
            f"unknown objective rule {objective_rule!r}; choose one of {', '.join(OBJECTIVE_RULES)}"
        )
    return str(objective_rule)


class PolicyError(ValueError):
    """θ, an action index or a schedule that the policy cannot accept."""


class PressureLimitError(PolicyError):
    """A pressure schedule outside the limits; the message names chamber, step and value."""

    def __init__(self, message: str, *, chamber: int, step: int, value_pa: float) -> None:
        super().__init__(message)
        self.chamber = chamber
        self.step = step
        self.value_pa = value_pa

    def __reduce__(self) -> tuple:
        # Keyword-only fields: pickle (process pools) needs to be told how to rebuild them.
        return (_rebuild_limit_error, (str(self), self.chamber, self.step, self.value_pa))


def _rebuild_limit_error(
    message: str, chamber: int, step: int, value_pa: float
) -> PressureLimitError:
    return PressureLimitError(message, chamber=chamber, step=step, value_pa=value_pa)


def policy_dim(horizon: int, with_release: bool) -> int:
    """D, the length of θ: one per control step, plus one for the release step."""
    return int(horizon) + int(with_release)


def check_release_step(
    release_step: Any, *, horizon: int, with_release: bool, owner: str = "this policy"
) -> int | None:
    """The release step as an int in 1..``horizon`` (1-based: the object is released at the end
    of that control step), or None for a policy without one; ``owner`` names the policy in the
    messages ("throw", "this experiment", ...).

    Raises:
        PolicyError: a missing, non-integer or out-of-range release step, or one given to a
            policy without a release step.
    """
    if not with_release:
        if release_step is not None:
            raise PolicyError(
                f"{owner} has no release step (release_step applies to "
                f"{', '.join(sorted(RELEASE_TASKS))} only), got {release_step!r}"
            )
        return None
    if release_step is None:
        raise PolicyError(f"{owner} needs release_step in 1..{horizon}")
    if isinstance(release_step, bool) or not isinstance(release_step, int | np.integer):
        raise PolicyError(f"release_step must be an integer in 1..{horizon}, got {release_step!r}")
    if not 1 <= int(release_step) <= horizon:
        raise PolicyError(f"release_step must be in 1..{horizon}, got {release_step}")
    return int(release_step)


@dataclass(frozen=True)
class PressureLimits:
    """Hardware limits: offsets of at most ``max_step_pa`` around per-chamber nominal pressures.

    Attributes:
        nominal_pa: 12 nominal chamber pressures, Pa (chamber order as above).
        max_step_pa: largest offset from nominal any chamber may get, Pa (paper: 30 kPa).
        source_pa: supply pressure, Pa; no chamber may exceed it (paper: about 205 kPa).
    """

    nominal_pa: tuple[float, ...] = (100_000.0,) * N_CHAMBERS
    max_step_pa: float = 30_000.0
    source_pa: float = 205_000.0

    def __post_init__(self) -> None:
        nominal = tuple(float(v) for v in np.broadcast_to(self.nominal_pa, (N_CHAMBERS,)))
        object.__setattr__(self, "nominal_pa", nominal)
        if not all(math.isfinite(v) for v in (*nominal, self.max_step_pa, self.source_pa)):
            raise PolicyError("pressure limits must be finite numbers")
        if self.max_step_pa <= 0:
            raise PolicyError(f"max_step_pa must be > 0 Pa, got {self.max_step_pa:g}")
        if self.source_pa <= 0:
            raise PolicyError(f"source_pa must be > 0 Pa, got {self.source_pa:g}")
        for c, p in enumerate(nominal):
            lo, hi = p - self.max_step_pa, p + self.max_step_pa
            if lo < 0 or hi > self.source_pa:
                raise PolicyError(
                    f"chamber {CHAMBER_NAMES[c]}: nominal {p:g} Pa ± max step "
                    f"{self.max_step_pa:g} Pa spans [{lo:g}, {hi:g}] Pa, outside "
                    f"[0, source {self.source_pa:g}] Pa"
                )

    @property
    def lower_pa(self) -> np.ndarray:
        """(12,) lowest allowed pressure per chamber, Pa."""
        return np.asarray(self.nominal_pa) - self.max_step_pa

    @property
    def upper_pa(self) -> np.ndarray:
        """(12,) highest allowed pressure per chamber, Pa."""
        return np.asarray(self.nominal_pa) + self.max_step_pa


def _kpa(value_pa: float) -> str:
    return f"{value_pa / 1000.0:g} kPa"


@dataclass(frozen=True)
class HardwareCeilings:
    """A robot's absolute ceilings, Pa: no experiment's limits or schedule may go beyond them.

    The server reads them from its settings (``HANDFUL_ROBOT__*``) and a hardware driver
    declares its own (``Driver.ceilings``); an experiment's ``PressureLimits`` may only narrow
    them. Messages name the values in kPa, the unit an operator types.

    Attributes:
        source_pa: supply pressure; no limits' source and no chamber above it (paper: ~205 kPa).
        max_step_pa: largest offset from nominal any experiment may allow (paper: 30 kPa).
        chamber_max_pa: the chambers' own rating (the simulator's range: 275.8 kPa, 40 psi).
    """

    source_pa: float = 205_000.0
    max_step_pa: float = 30_000.0
    chamber_max_pa: float = SIM_MAX_PRESSURE_PA

    def __post_init__(self) -> None:
        for name in ("source_pa", "max_step_pa", "chamber_max_pa"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise PolicyError(f"ceiling {name} must be a finite number > 0 Pa, got {v!r}")

    @property
    def top_pa(self) -> float:
        """The highest pressure any chamber may ever get: min(source, chamber max)."""
        return min(self.source_pa, self.chamber_max_pa)

    def check_limits(self, limits: PressureLimits) -> None:
        """Refuse limits wider than these ceilings (PolicyError naming the field, in kPa)."""
        if limits.source_pa > self.source_pa:
            raise PolicyError(
                f"source pressure {_kpa(limits.source_pa)} is above this robot's ceiling of "
                f"{_kpa(self.source_pa)}"
            )
        if limits.max_step_pa > self.max_step_pa:
            raise PolicyError(
                f"maximum step {_kpa(limits.max_step_pa)} is above this robot's ceiling of "
                f"{_kpa(self.max_step_pa)}"
            )
        top = float(np.max(limits.upper_pa))
        if top > self.top_pa:
            c = int(np.argmax(limits.upper_pa))
            raise PolicyError(
                f"chamber {CHAMBER_NAMES[c]}: nominal {_kpa(limits.nominal_pa[c])} + step "
                f"{_kpa(limits.max_step_pa)} reaches {_kpa(top)}, above this robot's chamber "
                f"ceiling of {_kpa(self.top_pa)}"
            )

    def check_schedule(
        self, pressure_schedule_pa: np.ndarray, nominal_pa: np.ndarray | float
    ) -> np.ndarray:
        """Refuse a schedule above ``top_pa`` or further than ``max_step_pa`` from nominal."""
        schedule = check_schedule(pressure_schedule_pa, lower_pa=0.0, upper_pa=self.top_pa)
        nominal = np.broadcast_to(np.asarray(nominal_pa, dtype=np.float64), (N_CHAMBERS,))
        off = np.abs(schedule - nominal) > self.max_step_pa + 1e-6
        if off.any():
            step, chamber = (int(i) for i in np.argwhere(off)[0])
            value = float(schedule[step, chamber])
            raise PressureLimitError(
                f"step {step + 1}, chamber {CHAMBER_NAMES[chamber]}: {_kpa(value)} is more than "
                f"this robot's maximum step of {_kpa(self.max_step_pa)} from nominal "
                f"{_kpa(nominal[chamber])}",
                chamber=chamber,
                step=step + 1,
                value_pa=value,
            )
        return schedule


def check_schedule(
    pressure_schedule_pa: npt.ArrayLike,
    *,
    lower_pa: np.ndarray | float = 0.0,
    upper_pa: np.ndarray | float = SIM_MAX_PRESSURE_PA,
    tolerance_pa: float = 1e-6,
) -> np.ndarray:
    """Validate an (H, 12) schedule in Pa against per-chamber bounds; return it as float64.

    Raises:
        PolicyError: wrong shape or non-finite values.
        PressureLimitError: a value outside [lower, upper]; names chamber, step (1-based), value.
    """
    try:
        schedule = np.asarray(pressure_schedule_pa, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PolicyError(f"pressure schedule is not numeric: {exc}") from None
    if schedule.ndim != 2 or schedule.shape[1] != N_CHAMBERS or schedule.shape[0] < 1:
        raise PolicyError(
            f"pressure schedule must have shape (H, {N_CHAMBERS}) with H ≥ 1, "
            f"got {tuple(schedule.shape)}"
        )
    bad = ~np.isfinite(schedule)
    if bad.any():
        step, chamber = (int(i) for i in np.argwhere(bad)[0])
        raise PressureLimitError(
            f"step {step + 1}, chamber {CHAMBER_NAMES[chamber]}: pressure is "
            f"{schedule[step, chamber]!r}, not a finite number",
            chamber=chamber,
            step=step + 1,
            value_pa=float(schedule[step, chamber]),
        )
    lo = np.broadcast_to(np.asarray(lower_pa, dtype=np.float64), (N_CHAMBERS,))
    hi = np.broadcast_to(np.asarray(upper_pa, dtype=np.float64), (N_CHAMBERS,))
    outside = (schedule < lo - tolerance_pa) | (schedule > hi + tolerance_pa)
    if outside.any():
        step, chamber = (int(i) for i in np.argwhere(outside)[0])
        value = float(schedule[step, chamber])
        raise PressureLimitError(
            f"step {step + 1}, chamber {CHAMBER_NAMES[chamber]}: {value:.1f} Pa is outside "
            f"the allowed [{lo[chamber]:.1f}, {hi[chamber]:.1f}] Pa",
            chamber=chamber,
            step=step + 1,
            value_pa=value,
        )
    return schedule


@dataclass(frozen=True)
class DecodedPolicy:
    """What θ means on the robot.

    Attributes:
        action_indices: (H,) ints in [0, P^6).
        level_indices: (H, 6) ints in [0, P), one per paired command.
        pressure_schedule_pa: (H, 12) commanded pressures, Pa; row t is held for 5 s / H.
        release_step: 1-based control step at whose end the object is released (throw), else None.
    """

    action_indices: np.ndarray
    level_indices: np.ndarray
    pressure_schedule_pa: np.ndarray
    release_step: int | None


@dataclass(frozen=True)
class Policy:
    """θ ∈ [0,1]^D ↔ pressure schedule, as in the paper (D = H, plus one for ``release_step``).

    Sim mode (``limits is None``): each paired command spans [p_min, p_max] = [0, 275.8 kPa],
    and the partner chamber gets ``p_min + p_max − p_plus``.
    Hardware mode: levels span the offset δ ∈ [−max_step, +max_step]; the "+" chamber gets
    nominal + δ, its partner nominal − δ.
    """

    levels: int
    horizon: int = HORIZON
    with_release: bool = False
    p_min_pa: float = 0.0
    p_max_pa: float = SIM_MAX_PRESSURE_PA
    limits: PressureLimits | None = field(default=None)

    def __post_init__(self) -> None:
        if not isinstance(self.levels, int | np.integer) or self.levels < 2:
            raise PolicyError(f"levels (P) must be an integer ≥ 2, got {self.levels!r}")
        if self.levels > 1000:
            raise PolicyError(f"levels (P) must be ≤ 1000, got {self.levels}")
        if not isinstance(self.horizon, int | np.integer) or not 1 <= self.horizon <= 1000:
            raise PolicyError(f"horizon (H) must be an integer in [1, 1000], got {self.horizon!r}")
        if not (0 <= self.p_min_pa < self.p_max_pa):
            raise PolicyError(
                f"need 0 ≤ p_min < p_max, got p_min={self.p_min_pa:g}, p_max={self.p_max_pa:g}"
            )

    # --- sizes -------------------------------------------------------------------------------
    @property
    def n_actions(self) -> int:
        """M = P^6, the size of the paired, discretised action set."""
        return int(self.levels) ** N_PAIRED

    @property
    def dim(self) -> int:
        """D: H, plus one for the release step when throwing."""
        return policy_dim(self.horizon, self.with_release)

    @property
    def step_s(self) -> float:
        """Seconds each schedule row is held: 5 s / H."""
        return EPISODE_S / self.horizon

    # --- pressure levels -----------------------------------------------------------------------
    def level_pressures_pa(self) -> np.ndarray:
        """(12, P): the pressure of each chamber at each level of its paired command, Pa."""
        frac = np.linspace(0.0, 1.0, self.levels)
        out = np.empty((N_CHAMBERS, self.levels))
        if self.limits is None:
            plus = self.p_min_pa + frac * (self.p_max_pa - self.p_min_pa)
            minus = self.p_min_pa + self.p_max_pa - plus
            for u in range(N_PAIRED):
                out[2 * u], out[2 * u + 1] = plus, minus
        else:
            delta = -self.limits.max_step_pa + frac * 2.0 * self.limits.max_step_pa
            nominal = np.asarray(self.limits.nominal_pa)
            for u in range(N_PAIRED):
                out[2 * u] = nominal[2 * u] + delta
                out[2 * u + 1] = nominal[2 * u + 1] - delta
        return out

    def bounds_pa(self) -> tuple[np.ndarray, np.ndarray]:
        """(12,), (12,): the lowest and highest pressure this policy may command, Pa."""
        if self.limits is None:
            return (np.full(N_CHAMBERS, self.p_min_pa), np.full(N_CHAMBERS, self.p_max_pa))
        return self.limits.lower_pa, self.limits.upper_pa

    # --- θ ↔ actions ----------------------------------------------------------------------------
    def _check_theta(self, theta: np.ndarray) -> np.ndarray:
        try:
            th = np.asarray(theta, dtype=np.float64)
        except (TypeError, ValueError):
            raise PolicyError(f"θ must be a list of {self.dim} numbers in [0, 1]") from None
        if th.shape != (self.dim,):
            raise PolicyError(
                f"θ must have {self.dim} entries (H={self.horizon}"
                f"{' + release step' if self.with_release else ''}), got shape {th.shape}"
            )
        if not np.all(np.isfinite(th)):
            raise PolicyError(f"θ must be finite, got {th.tolist()}")
        outside = np.flatnonzero((th < 0.0) | (th > 1.0))
        if outside.size:
            i = int(outside[0])
            raise PolicyError(f"θ[{i}] = {float(th[i])!r} is outside [0, 1]")
        return th

    def _actions_of(self, theta: np.ndarray) -> np.ndarray:
        """(..., D) θ → (..., H) action indices: floor(θ·M), with M clipped to M − 1."""
        m = self.n_actions
        return np.minimum(np.floor(theta[..., : self.horizon] * m).astype(np.int64), m - 1)

    def _release_index_of(self, theta: np.ndarray) -> np.ndarray:
        """(..., D) θ → (...) 0-based release index (release_step − 1): floor(θ_H·H) ≤ H − 1."""
        h = self.horizon
        return np.minimum(np.floor(theta[..., h] * h).astype(np.int64), h - 1)

    def actions_from_theta(self, theta: np.ndarray) -> tuple[np.ndarray, int | None]:
        """g: θ (D,) → (action indices (H,), release_step or None). Floors θ·M, clips M → M−1."""
        th = self._check_theta(theta)
        release = int(self._release_index_of(th)) + 1 if self.with_release else None
        return self._actions_of(th), release

    def theta_from_actions(
        self, actions: np.ndarray, release_step: int | None = None
    ) -> np.ndarray:
        """Inverse of g: the centre of each action's θ bin, so decode(encode(a)) == a. (D,)."""
        a = np.asarray(actions, dtype=np.int64)
        if a.shape != (self.horizon,):
            raise PolicyError(f"need {self.horizon} action indices, got shape {a.shape}")
        if a.min() < 0 or a.max() >= self.n_actions:
            raise PolicyError(f"action indices must lie in [0, {self.n_actions}), got {a.tolist()}")
        release = check_release_step(
            release_step, horizon=self.horizon, with_release=self.with_release
        )
        return self._bin_centres(a, None if release is None else np.int64(release - 1))

    def _bin_centres(
        self, actions: npt.ArrayLike, release_index: npt.ArrayLike | None
    ) -> np.ndarray:
        """(..., H) action indices and (...) 0-based release indices → (..., D) θ at the
        centres of their bins."""
        theta = (np.asarray(actions).astype(np.float64) + 0.5) / self.n_actions
        if release_index is None:
            return theta
        release = (np.asarray(release_index, dtype=np.float64) + 0.5) / self.horizon
        return np.concatenate([theta, release[..., None]], axis=-1)

    # --- θ ↔ grid coordinates (batched) ---------------------------------------------------------
    def grid_sizes(self) -> tuple[int, ...]:
        """The number of values of each grid coordinate (see ``grid_from_theta``)."""
        return (self.levels,) * (self.horizon * N_PAIRED) + (self.horizon,) * self.with_release

    def grid_from_theta(self, theta: np.ndarray) -> np.ndarray:
        """(N, D) θ (unchecked) → (N, G) grid coordinates: the H × 6 level indices of the
        decoded schedule (step by step, paired commands in order), then release_step − 1 when
        throwing. Equal rows ⇔ the same schedule and release step."""
        th = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        levels = self.levels_from_actions(self._actions_of(th))
        levels = levels.reshape(th.shape[0], self.horizon * N_PAIRED)
        if not self.with_release:
            return levels
        return np.concatenate([levels, self._release_index_of(th)[:, None]], axis=1)

    def theta_from_grid(self, grid: np.ndarray) -> np.ndarray:
        """(N, G) grid coordinates → (N, D) θ at the centres of their bins (inverse of
        ``grid_from_theta``)."""
        g = np.atleast_2d(np.asarray(grid, dtype=np.int64))
        n_levels = self.horizon * N_PAIRED
        levels = g[:, :n_levels].reshape(g.shape[0], self.horizon, N_PAIRED)
        actions = np.ravel_multi_index(tuple(np.moveaxis(levels, -1, 0)), (self.levels,) * N_PAIRED)
        return self._bin_centres(actions, g[:, n_levels] if self.with_release else None)

    # --- actions ↔ schedule ---------------------------------------------------------------------
    def levels_from_actions(self, actions: np.ndarray) -> np.ndarray:
        """(H,) action indices → (H, 6) level index per paired command (C order digits)."""
        digits = np.unravel_index(np.asarray(actions, dtype=np.int64), (self.levels,) * N_PAIRED)
        return np.stack(digits, axis=-1)

    def schedule_from_levels(self, level_indices: np.ndarray) -> np.ndarray:
        """(H, 6) level indices → (H, 12) pressure schedule, Pa."""
        table = self.level_pressures_pa()  # (12, P)
        lv = np.asarray(level_indices, dtype=np.int64)
        chamber_levels = np.repeat(lv, 2, axis=1)  # both chambers of a pair share the level
        return table[np.arange(N_CHAMBERS)[None, :], chamber_levels]

    def decode(self, theta: np.ndarray) -> DecodedPolicy:
        """θ (D,) → the schedule the robot runs. Checked against this policy's limits."""
        actions, release = self.actions_from_theta(theta)
        levels = self.levels_from_actions(actions)
        schedule = self.schedule_from_levels(levels)
        self.check(schedule)
        return DecodedPolicy(actions, levels, schedule, release)

    def check(self, pressure_schedule_pa: np.ndarray) -> np.ndarray:
        """Refuse an (H, 12) schedule outside this policy's pressure bounds (see check_schedule)."""
        lo, hi = self.bounds_pa()
        if self.limits is not None:
            lo, hi = np.maximum(lo, 0.0), np.minimum(hi, self.limits.source_pa)
        schedule = check_schedule(pressure_schedule_pa, lower_pa=lo, upper_pa=hi)
        if schedule.shape[0] != self.horizon:
            raise PolicyError(
                f"pressure schedule has {schedule.shape[0]} steps, this policy has H={self.horizon}"
            )
        return schedule

    def encode(
        self,
        pressure_schedule_pa: np.ndarray,
        release_step: int | None = None,
        *,
        snap: bool = False,
    ) -> np.ndarray:
        """Schedule (H, 12) → θ (D,) at the centre of its actions' bins (decode ∘ encode is the
        identity on the grid).

        Exact (default): the schedule must lie within this policy's bounds and on its level
        grid, else PolicyError. ``snap=True`` (a schedule a robot executed, possibly off the
        grid or beyond the bounds): each pair goes to its nearest level (least mean absolute
        error over its two chambers); only the shape and finiteness are checked.
        """
        if snap:
            try:
                schedule = np.asarray(pressure_schedule_pa, dtype=np.float64)
            except (TypeError, ValueError):
                schedule = np.full((0, 0), np.nan)  # ragged or not numeric: refused below
            if schedule.shape != (self.horizon, N_CHAMBERS) or not np.all(np.isfinite(schedule)):
                raise PolicyError(
                    f"pressure schedule must be {self.horizon}×{N_CHAMBERS} finite numbers (Pa), "
                    f"got shape {schedule.shape}"
                )
        else:
            schedule = self.check(pressure_schedule_pa)
        table = self.level_pressures_pa().reshape(N_PAIRED, 2, self.levels)  # (6, 2, P)
        pairs = schedule.reshape(self.horizon, N_PAIRED, 2)
        err = np.abs(table[None] - pairs[..., None])  # (H, 6, 2, P)
        if snap:
            levels = np.argmin(err.mean(axis=2), axis=-1)
        else:
            worst = err.max(axis=2)  # (H, 6, P)
            levels = np.argmin(worst, axis=-1)
            tol = 1e-6 * max(1.0, float(np.abs(table).max()))
            off = np.take_along_axis(worst, levels[..., None], axis=-1)[..., 0] > tol
            if off.any():
                u, t = (int(i) for i in np.argwhere(off.T)[0])
                raise PolicyError(
                    f"step {t + 1}, pair {PAIRED_NAMES[u]}: pressures "
                    f"{schedule[t, 2 * u : 2 * u + 2].tolist()} Pa "
                    f"are not one of the policy's {self.levels} paired levels"
                )
        actions = np.ravel_multi_index(tuple(levels.T), (self.levels,) * N_PAIRED)
        return self.theta_from_actions(np.asarray(actions), release_step)

    def executed_theta(
        self,
        planned_theta: np.ndarray,
        executed_schedule_pa: np.ndarray,
        executed_release_step: int | None = None,
    ) -> np.ndarray:
        """The θ an optimiser observes for a trial: the one rule for the executed θ.

        The planned θ when what ran snaps (``encode(..., snap=True)``) to the planned
        actions and release step, i.e. the trial ran its plan (a simulator exactly, a robot
        within half a level); otherwise the centre of the bins of what ran. So the service's
        runs, workers' results, imports and the sweep all give the optimiser its own θ back
        for a trial that ran as planned.
        """
        planned = np.asarray(planned_theta, dtype=np.float64)
        ran = self.encode(executed_schedule_pa, executed_release_step, snap=True)
        same = np.array_equal(self.grid_from_theta(ran), self.grid_from_theta(planned))
        return planned.copy() if same else ran


def schedule_hash(pressure_schedule_pa: npt.ArrayLike, release_step: int | None = None) -> str:
    """SHA-256 (hex) of a schedule as the robot would run it: what an operator's confirmation binds.

    The schedule (H, 12) Pa is rounded to 1 mPa before hashing, so JSON round trips of the
    same numbers give the same hash while any real change gives a different one.
    """
    schedule = np.asarray(pressure_schedule_pa, dtype=np.float64)
    finite = np.isfinite(schedule)
    millipascals = np.round(np.where(finite, schedule, 0.0) * 1000.0).astype(np.int64)
    # A forged or corrupted schedule still hashes (so it can be refused by name, never
    # crash a read); its NaN/inf entries hash as themselves, unlike any real schedule.
    if finite.all():  # every real schedule: the same cells, built in C
        cells: list[Any] = millipascals.tolist()
    else:
        cells = [
            [int(v) if ok else repr(float(x)) for v, ok, x in zip(r_v, r_ok, r_x, strict=True)]
            for r_v, r_ok, r_x in zip(millipascals, finite, schedule, strict=True)
        ]
    payload = {
        "pressure_schedule_mpa": cells,
        "release_step": None if release_step is None else int(release_step),
    }
    blob = json.dumps(payload, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()
