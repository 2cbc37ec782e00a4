"""What a sweep runs: one ``RunSpec`` per (method, task, P, seed), and the checks on a sweep's
arguments."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from app.optim import METHODS, OptimizerSpec, SettingsError
from app.policy import (
    COMMAND_HOLDS,
    HORIZON,
    OBJECTIVE_RULES,
    RELEASE_TASKS,
    TASKS,
    policy_dim,
)
from app.rl.settings import RL_METHODS, REDQSettings

# Rough cost per trial, cheapest first: a sweep runs larger P first, cheap methods first within
# a P, so an interrupted sweep still leaves complete rows for them.
COST_RANK = {
    "random": 0, "cem": 0, "cmaes": 0, "optuna-tpe": 1, "bo-lei": 2, "bo-levels": 3,
    "optuna-gp": 4, "bo-ucb": 5, "bo-lei-default": 6, "bo-turbo": 6, "bo-lei-distinct": 6,
    "redq": 7, "redq-joints": 7,
}  # fmt: skip
#: what a sweep runs: the optimisers the trial service offers (``app.optim.METHODS``), then the
#: benchmark-only RL methods (REDQ, ``app.rl``; the service does not offer them)
SWEEP_METHODS: tuple[str, ...] = (*METHODS, *RL_METHODS)
#: P of an RL method's runs: it commands continuous pressures, no discretisation
RL_LEVELS = 0


#: Settings that say where a run computes, not what it computes: not part of its cache key,
#: so a REDQ run started with ``device=cpu`` can be continued with ``device=cuda``.
EXECUTION_SETTINGS: frozenset[str] = frozenset({"device", "checkpoint_every"})


@dataclass(frozen=True)
class RunSpec:
    """One optimisation run: ``budget`` trials of ``method`` on ``task`` with P = ``levels``."""

    method: str
    task: str
    levels: int
    seed: int
    budget: int
    preset: str = "reference"
    settings: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    label: str | None = None
    command_hold: str = "zero"
    objective_rule: str = "paper"

    @property
    def name(self) -> str:
        """The method's name in outputs: ``label`` (a variant with its own settings) or method."""
        return self.label or self.method

    @property
    def key(self) -> str:
        """File-name stem of this run's cache (the budget is not part of it: longer runs reuse).
        Settings without a label of their own add a short tag of them, so runs never mix;
        ``EXECUTION_SETTINGS`` (where the run computes) are not part of it."""
        key = (
            f"{self.task}_P{self.levels}_{self.name}_s{self.seed}_{self.preset}"
            f"_{self.command_hold}_{self.objective_rule}"
        )
        identity = {k: v for k, v in self.settings.items() if k not in EXECUTION_SETTINGS}
        if identity and self.label is None:
            blob = json.dumps(identity, sort_keys=True, default=str)
            key += "_" + hashlib.sha1(blob.encode()).hexdigest()[:8]
        return key

    @property
    def is_rl(self) -> bool:
        """An RL method (REDQ): an agent acting per control step instead of an optimiser."""
        return self.method in RL_METHODS

    @property
    def with_release(self) -> bool:
        """Throwing has the release step as an extra policy parameter."""
        return self.task in RELEASE_TASKS

    def optimizer_spec(self) -> OptimizerSpec:
        """The optimiser this run uses (built as the service builds an experiment's)."""
        return OptimizerSpec(
            self.method,
            levels=self.levels,
            horizon=HORIZON,
            with_release=self.with_release,
            seed=self.seed,
            settings=self.settings,
        )

    def cost_rank(self) -> tuple[int, int]:
        """Sort key: larger P first, then cheaper methods first."""
        return (-self.levels, COST_RANK.get(self.method, 9))


def validate(
    *,
    methods: Sequence[str],
    tasks: Sequence[str],
    levels: Sequence[int],
    budgets: Sequence[int],
    seeds: int,
    command_hold: str = "zero",
    objective_rule: str = "paper",
) -> None:
    """Raise SettingsError (one line, naming the culprit) for arguments no sweep can run."""
    if command_hold not in COMMAND_HOLDS:
        raise SettingsError(
            f"unknown command hold {command_hold!r}; choose from {', '.join(COMMAND_HOLDS)}"
        )
    if objective_rule not in OBJECTIVE_RULES:
        raise SettingsError(
            f"unknown objective rule {objective_rule!r}; choose from {', '.join(OBJECTIVE_RULES)}"
        )
    for m in methods:
        if m not in SWEEP_METHODS:
            raise SettingsError(f"unknown method {m!r}; choose from {', '.join(SWEEP_METHODS)}")
    for t in tasks:
        if t not in TASKS:
            raise SettingsError(f"unknown task {t!r}; choose from {', '.join(TASKS)}")
    for p in levels:
        if p < 2:
            raise SettingsError(f"levels (P) must be ≥ 2, got {p}")
    for b in budgets:
        if b < 1:
            raise SettingsError(f"budget must be ≥ 1 trial, got {b}")
    if seeds < 1:
        raise SettingsError(f"seeds must be ≥ 1, got {seeds}")
    if not (methods and tasks and levels and budgets):
        raise SettingsError("need at least one method, task, level count and budget")


def make_specs(
    *,
    methods: Sequence[str],
    tasks: Sequence[str],
    levels: Sequence[int],
    budgets: Sequence[int],
    seeds: int,
    preset: str,
    command_hold: str = "zero",
    objective_rule: str = "paper",
    rl_settings: dict[str, Any] | None = None,
) -> list[RunSpec]:
    """All runs of a sweep, each as long as the largest budget. An RL method runs once per
    (task, seed), with P = ``RL_LEVELS`` (it needs no P), and ``rl_settings`` (REDQSettings
    fields; checked here)."""
    validate(
        methods=methods,
        tasks=tasks,
        levels=levels,
        budgets=budgets,
        seeds=seeds,
        command_hold=command_hold,
        objective_rule=objective_rule,
    )
    rl = dict(rl_settings or {})
    for m in methods:
        if m in RL_METHODS:
            check_rl_settings(m, rl)
    n = max(budgets)
    specs = {
        RunSpec(
            m,
            t,
            RL_LEVELS if m in RL_METHODS else p,
            s,
            n,
            preset,
            settings=rl if m in RL_METHODS else {},
            command_hold=command_hold,
            objective_rule=objective_rule,
        ): None
        for t in tasks
        for p in levels
        for m in methods
        for s in range(seeds)
    }
    return list(specs)


def check_rl_settings(method: str, settings: dict[str, Any]) -> REDQSettings:
    """The REDQ settings of an RL run; SettingsError (one line) for a bad one."""
    return REDQSettings.for_method(method, settings)


def task_dim(task: str) -> int:
    """D of the paper's policy for ``task`` (H = 10, plus the release step when throwing)."""
    return policy_dim(HORIZON, task in RELEASE_TASKS)
