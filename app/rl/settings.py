"""REDQ's settings, checked without torch or MuJoCo (the sweep checks them before it runs)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from app.optim.base import SettingsError

#: sweep method → the observation set its environment gives (``app.rl.env``)
RL_METHODS: dict[str, str] = {"redq": "task", "redq-joints": "joints"}
OBSERVATION_SETS: tuple[str, ...] = ("task", "joints")


@dataclass(frozen=True)
class REDQSettings:
    """REDQ as the paper ran it (its settings are the defaults where it gives them).

    Attributes:
        hidden_sizes: hidden layers of the policy and of each critic (paper: two of 256).
        ensemble_size: critics in the ensemble, N (paper: 2).
        subset_size: critics the target's minimum is taken over, M (REDQ: 2).
        utd: update-to-data ratio, gradient updates per environment transition (paper: 16).
        pretrain_episodes: episodes of uniformly random commands before learning starts; they
            are trials 1..n of the run (paper: 250 trials, 2,500 transitions).
        batch_size, gamma, tau, lr: REDQ's own defaults (not given by the paper).
        observations: "task" (end-effector velocity, object position) or "joints" (also the
            joints' (u, v) and rates).
        device: torch device of the networks.
        checkpoint_every: a sweep run saves the agent every this many episodes (resume point).
    """

    hidden_sizes: tuple[int, ...] = (256, 256)
    ensemble_size: int = 2
    subset_size: int = 2
    utd: int = 16
    pretrain_episodes: int = 250
    batch_size: int = 256
    gamma: float = 0.99
    tau: float = 0.005
    lr: float = 3e-4
    observations: str = "task"
    device: str = "cpu"
    checkpoint_every: int = 25

    @classmethod
    def for_method(cls, method: str, settings: Mapping[str, Any] | None = None) -> REDQSettings:
        """The settings of sweep method ``method`` (``redq``: task observations, ``redq-joints``:
        with the joint states) updated by ``settings``; SettingsError (one line) if bad."""
        if method not in RL_METHODS:
            raise SettingsError(
                f"{method!r} is not an RL method; choose from {', '.join(RL_METHODS)}"
            )
        given = dict(settings or {})
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(given) - names)
        if unknown:
            raise SettingsError(
                f"unknown REDQ setting {unknown[0]!r}; known: {', '.join(sorted(names))}"
            )
        if "observations" in given and given["observations"] != RL_METHODS[method]:
            raise SettingsError(
                f"{method} observes {RL_METHODS[method]!r}; use the other method for "
                f"{given['observations']!r}"
                if given["observations"] in OBSERVATION_SETS
                else f"unknown observation set {given['observations']!r}; choose one of "
                + ", ".join(OBSERVATION_SETS)
            )
        given["observations"] = RL_METHODS[method]
        if "hidden_sizes" in given:
            given["hidden_sizes"] = tuple(given["hidden_sizes"])
        return cls(**given).checked()

    def checked(self) -> REDQSettings:
        """Self if every setting is usable; SettingsError naming the first bad one."""

        def whole(name: str, low: int) -> None:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise SettingsError(f"REDQ {name} must be a whole number ≥ {low}, got {v!r}")

        if isinstance(self.utd, bool) or not isinstance(self.utd, int) or self.utd <= 0:
            raise SettingsError(
                f"REDQ utd (gradient updates per environment transition) must be a whole "
                f"number ≥ 1, got {self.utd!r}"
            )
        whole("ensemble_size", 1)
        whole("subset_size", 1)
        whole("pretrain_episodes", 0)
        whole("batch_size", 1)
        whole("checkpoint_every", 1)
        if self.subset_size > self.ensemble_size:
            raise SettingsError(
                f"REDQ subset_size ({self.subset_size}) must be ≤ ensemble_size "
                f"({self.ensemble_size})"
            )
        if not self.hidden_sizes or any(
            isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in self.hidden_sizes
        ):
            raise SettingsError(
                f"REDQ hidden_sizes must be whole numbers ≥ 1, got {self.hidden_sizes!r}"
            )
        for name, lo, hi in (("gamma", 0.0, 1.0), ("tau", 0.0, 1.0)):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and lo <= v <= hi):
                raise SettingsError(f"REDQ {name} must be in [{lo:g}, {hi:g}], got {v!r}")
        if not (isinstance(self.lr, int | float) and math.isfinite(self.lr) and self.lr > 0):
            raise SettingsError(f"REDQ lr must be a positive number, got {self.lr!r}")
        if self.observations not in OBSERVATION_SETS:
            raise SettingsError(
                f"unknown observation set {self.observations!r}; choose one of "
                + ", ".join(OBSERVATION_SETS)
            )
        return self
