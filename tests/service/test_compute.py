"""Optimiser work is bounded (issue 16, finding 4): sane settings only, a time budget that
stops the work (not just the wait), cancellation, and ``/model`` reusing the suggestion's fit."""

from __future__ import annotations

import math
import threading
import time

import pytest

from app.db.models import Trial
from app.service import compute, experiments, trials
from app.service import lifecycle as lc
from app.service.compute import ComputeCancelled, ComputeRunner, ComputeTimeout
from app.service.errors import InvalidInput


@pytest.mark.parametrize(
    ("method", "settings", "words"),
    [
        ("bo-lei-default", {"num_restarts": 1_000_000}, "num_restarts must be an integer in 1..64"),
        ("bo-lei-default", {"raw_samples": 10**7}, "raw_samples"),
        ("bo-lei-default", {"fit_maxiter": 10**9}, "fit_maxiter"),
        ("cem", {"population": 10**9}, "population"),
        ("cmaes", {"popsize": 10**6}, "popsize"),
    ],
)
def test_optimizer_settings_beyond_sane_ranges_are_refused(
    make_experiment, method, settings, words
):
    with pytest.raises(InvalidInput, match=words):
        make_experiment(method=method, optimizer_settings=settings)


def _alive(pids: list[int]) -> list[int]:
    import os

    out = []
    for pid in pids:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            continue
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split()[2] == "Z":  # a zombie is dead
                    continue
        except FileNotFoundError:
            continue
        out.append(pid)
    return out


def test_a_job_past_its_budget_is_stopped_and_the_next_one_runs():
    runner = ComputeRunner(workers=1, timeout_s=60.0)
    try:
        assert runner.call(math.sqrt, 4.0) == 2.0  # the process is started (spawn)
        runner.timeout_s = 1.0
        pids = list(runner._pools[0]._processes)
        t0 = time.monotonic()
        with pytest.raises(ComputeTimeout, match="within its 1 s budget"):
            runner.call(time.sleep, 60)
        assert time.monotonic() - t0 < 3
        time.sleep(0.2)
        assert _alive(pids) == []  # the work was stopped, not just the wait
        runner.timeout_s = 60.0
        assert runner.call(math.sqrt, 9.0) == 3.0
    finally:
        runner.shutdown()


def test_a_job_whose_client_left_is_stopped():
    runner = ComputeRunner(workers=1, timeout_s=60.0)
    try:
        runner.call(math.sqrt, 1.0)
        pids = list(runner._pools[0]._processes)
        left = threading.Event()
        threading.Timer(0.5, left.set).start()
        t0 = time.monotonic()
        with pytest.raises(ComputeCancelled):
            runner.call(time.sleep, 60, cancelled=left)
        assert time.monotonic() - t0 < 3
        time.sleep(0.2)
        assert _alive(pids) == []
    finally:
        runner.shutdown()


def test_the_model_view_reuses_the_suggestions_fit(db, make_experiment, make_trial):
    exp_id = make_experiment(method="bo-lei-default", n_initial=2)
    for i, value in enumerate((0.2, 0.9, 0.5)):
        tid = make_trial(exp_id, status=lc.COMPLETED, theta=[0.1 + 0.3 * i] * 10)
        with db.write() as s:
            s.get(Trial, tid).objective = value
    with db.read() as s:
        inputs = trials.optimizer_inputs(s, experiments.get_experiment(s, exp_id))
    compute._fitted.clear()
    compute.suggest_job(inputs, 1)  # what a compute process does for POST .../suggest
    view, hit = compute.model_job(inputs, [0.5] * 10, 5)
    assert hit and len(view["slices"]) == 10 and view["lengthscales"]
    # a new observation: a new fit, cached in turn
    tid = make_trial(exp_id, status=lc.COMPLETED, theta=[0.95] * 10)
    with db.write() as s:
        s.get(Trial, tid).objective = 0.1
    with db.read() as s:
        newer = trials.optimizer_inputs(s, experiments.get_experiment(s, exp_id))
    assert not compute.model_job(newer, [0.5] * 10, 5)[1]
    assert compute.model_job(newer, [0.5] * 10, 5)[1]
