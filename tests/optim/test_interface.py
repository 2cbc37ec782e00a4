"""The optimiser interface: one factory, a typed surrogate, and a library that sets no global
state (no torch on import, torch's thread count left to the entry points)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from app.optim import (
    DEFAULT_METHOD,
    METHODS,
    OptimizerSpec,
    Surrogate,
    build_optimizer,
    make_optimizer,
)


def _python(code: str, **env: str) -> str:
    res = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **env},
    )
    assert res.returncode == 0, res.stderr
    return res.stdout.strip()


def test_method_names_load_without_torch_and_the_optimisers_without_the_simulator():
    out = _python(
        "import sys; from app.optim.methods import METHODS, DEFAULT_METHOD; import app.optim;"
        "print('torch' in sys.modules, any(m.startswith(('app.sim', 'app.bench'))"
        " for m in sys.modules), DEFAULT_METHOD in METHODS)"
    )
    assert out == "False False True"


def test_bo_leaves_torchs_thread_count_to_the_entry_point(monkeypatch):
    import torch

    calls: list[int] = []
    monkeypatch.setattr(torch, "set_num_threads", calls.append)
    opt = make_optimizer("bo-lei", 3, seed=0, num_restarts=2, raw_samples=16)
    x = np.random.default_rng(0).random((5, 3))
    opt.observe(x, x.sum(axis=1))
    opt.suggest(1)
    opt.predict(x)
    assert calls == []


def test_only_bo_methods_are_surrogates_and_their_n_initial_is_the_design_length():
    for method in METHODS:
        spec = OptimizerSpec(method, levels=3, horizon=4, with_release=True, seed=0)
        opt = build_optimizer(spec)
        assert opt.method == method
        assert isinstance(opt, Surrogate) == method.startswith("bo-"), method
        if isinstance(opt, Surrogate):
            assert opt.n_initial == spec.dim + 1


@pytest.mark.parametrize(
    ("method", "settings", "expected"),
    [
        # the experiment's BO columns reach BO methods only
        ("bo-lei", {}, {"acquisition": "ucb", "kappa": 2.0, "n_initial": 7}),
        ("cem", {}, {}),
        # the level grid's P and H where the method needs them ...
        (
            "bo-levels",
            {},
            {"acquisition": "ucb", "kappa": 2.0, "n_initial": 7, "levels": 5, "horizon": 10},
        ),
        # ... or the caller's settings do, unless the caller gave them
        (
            "bo-lei-default",
            {"initial_design": "corners", "levels": 3},
            {
                "acquisition": "ucb",
                "kappa": 2.0,
                "n_initial": 7,
                "initial_design": "corners",
                "levels": 3,
                "horizon": 10,
            },
        ),
    ],
)
def test_one_rule_turns_a_method_and_the_policy_into_settings(method, settings, expected):
    spec = OptimizerSpec(
        method,
        levels=5,
        horizon=10,
        with_release=False,
        seed=0,
        settings=settings,
        n_initial=7,
        acquisition="ucb",
        kappa=2.0,
    )
    assert spec.kwargs() == expected


def test_the_sweep_and_the_service_build_the_same_optimiser():
    """A sweep run and an experiment with the same method, P and seed suggest the same θ."""
    from app.bench import RunSpec
    from app.db.models import Experiment
    from app.service.experiments import optimizer_spec

    run = RunSpec("bo-levels", "throw", 3, 4, 10)
    # an experiment row as stored (not added to any database): every column it has is read
    exp = Experiment(
        method="bo-levels",
        levels=3,
        horizon=10,
        with_release=True,
        seed=4,
        optimizer_settings={},
        n_initial=12,  # what a new experiment stores: D + 1
        acquisition=None,
        kappa=None,
    )
    a, b = build_optimizer(run.optimizer_spec()), build_optimizer(optimizer_spec(exp))
    np.testing.assert_array_equal(a.suggest(3), b.suggest(3))
    assert DEFAULT_METHOD == "bo-lei-default"
    assert make_optimizer(DEFAULT_METHOD, 3, seed=0).method == DEFAULT_METHOD
