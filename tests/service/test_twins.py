"""Sim twins: every hardware trial gets a simulated run of exactly its schedule (planned, then
executed), stored beside it, with the experiment's hold and the sim prior's preset."""

from __future__ import annotations

import numpy as np
import pytest

from app.db.models import Trial
from app.policy import schedule_hash
from app.service import sim_prior, trials, twins
from app.sim import rollout

LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0}


def _ran(db, trial_id: int, schedule, objective: float) -> None:
    """What a hardware worker's result leaves on the trial: what ran, and its score."""
    with db.write() as s:
        row = s.get(Trial, trial_id)
        row.executed_pressure_schedule_pa = np.asarray(schedule, dtype=float).tolist()
        row.status, row.objective, row.n_measurements = "completed", objective, 1


def test_a_hardware_trial_gets_its_planned_and_executed_twins(db, make_experiment, make_trial):
    hw = make_experiment(target="hardware", levels=3, command_hold="linear", limits=LIMITS)
    sim = make_experiment(levels=3)  # sim trials get no twin
    a = make_trial(hw, theta=[0.9] * 10)
    b = make_trial(hw, theta=[0.1, 0.9] * 5)
    make_trial(sim)
    assert twins.run_pending(db) == 2
    assert twins.run_pending(db) == 0  # nothing left to make
    with db.read() as s:
        [planned] = twins.twins_of(s, a)
        trial = s.get(Trial, a)
        schedule = np.asarray(trial.pressure_schedule_pa)
    expected = rollout("tip_speed", schedule, preset="fast", command_hold="linear")
    assert (planned.kind, planned.status, planned.sim_preset, planned.command_hold) == (
        "planned",
        "done",
        "fast",  # no sim prior: the paper-matching default
        "linear",  # the experiment's own hold
    )
    assert planned.schedule_hash == schedule_hash(schedule)
    assert planned.predicted_objective == pytest.approx(expected.objective)
    assert planned.predicted_tip_speed == pytest.approx(expected.max_tip_speed)
    assert planned.bend_limit_hits == list(expected.bend_limit_hits)

    # a ran its plan: the executed twin reuses the planned one's numbers
    _ran(db, a, schedule, objective=1.25)
    # b ran something else (the robot could not follow): its executed schedule is simulated
    off = schedule - 5_000.0
    _ran(db, b, off, objective=0.5)
    assert twins.run_pending(db) == 2
    with db.read() as s:
        kinds_a = {t.kind: t for t in twins.twins_of(s, a)}
        kinds_b = {t.kind: t for t in twins.twins_of(s, b)}
        rows = {r.trial_id: r for r in twins.comparison(s, hw)}
    assert kinds_a["executed"].predicted_objective == planned.predicted_objective
    assert kinds_a["executed"].wall_s == 0.0  # not simulated again
    ran_b = rollout("tip_speed", off, preset="fast", command_hold="linear")
    assert kinds_b["executed"].schedule_hash == schedule_hash(off)
    assert kinds_b["executed"].predicted_objective == pytest.approx(ran_b.objective)
    # the page's comparison: hardware − twin, the twin of what executed
    assert rows[a].twin.kind == "executed"
    assert rows[a].discrepancy == pytest.approx(1.25 - planned.predicted_objective)
    assert rows[b].discrepancy == pytest.approx(0.5 - ran_b.objective)
    # the trial's detail carries them
    with db.read() as s:
        assert [t.kind for t in trials.read_trial(s, a).twins] == ["planned", "executed"]


def test_the_twin_runs_with_the_linked_sim_experiments_preset(db, make_experiment, make_trial):
    sim = make_experiment(levels=3, sim_preset="reference", limits=LIMITS)
    hw = make_experiment(target="hardware", levels=3, limits=LIMITS, sim_prior_experiment_id=sim)
    t = make_trial(hw)
    calls = []

    def call(job):
        calls.append(job)
        return twins.simulate(job)

    twins.run_pending(db, call=call)
    [job] = calls
    assert (job.preset, job.sim_experiment_id, job.command_hold) == ("reference", sim, "zero")
    with db.read() as s:
        [twin] = twins.twins_of(s, t)
        assert twin.sim_experiment_id == sim and twin.sim_preset == "reference"
        assert sim_prior.read_sim_prior(s, hw).twin_preset == "reference"


def test_a_compute_failure_is_retried_then_stored_as_an_error(db, make_experiment, make_trial):
    hw = make_experiment(target="hardware", levels=3, limits=LIMITS)
    t = make_trial(hw)
    failures: dict = {}

    def broken(job):
        raise RuntimeError("the compute process was stopped")

    for _ in range(twins.MAX_ATTEMPTS - 1):
        assert twins.run_pending(db, call=broken, failures=failures) == 0
        with db.read() as s:
            assert twins.twins_of(s, t) == []  # retried on the next round
    assert twins.run_pending(db, call=broken, failures=failures) == 1
    with db.read() as s:
        [twin] = twins.twins_of(s, t)
    assert twin.status == "error" and "the compute process was stopped" in twin.error
    assert twin.predicted_objective is None
