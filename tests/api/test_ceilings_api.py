"""The robot's absolute hardware ceilings (server settings): an experiment's limits can only
narrow them, and every route that creates limits or schedules checks them, in kPa."""

from __future__ import annotations

import pytest

from app.db.session import Database
from app.policy import HardwareCeilings
from app.service.auth import Actor
from app.service.experiments import create_experiment
from app.service.schemas import ExperimentCreate
from app.service.trials import attach

# A robot weaker than the paper's: 150 kPa supply, 20 kPa steps.
SERVER_ENV = {"HANDFUL_ROBOT__SOURCE_PA": "150000", "HANDFUL_ROBOT__MAX_STEP_PA": "20000"}

HW = {"name": "hw", "task": "tip_speed", "levels": 3, "method": "random", "target": "hardware"}


@pytest.mark.parametrize(
    ("limits", "words"),
    [
        # the 1e12 Pa slip of the issue: refused, in kPa
        ({"nominal_pa": 100_000.0, "max_step_pa": 20_000.0, "source_pa": 1e12}, "1e+09 kPa"),
        ({"nominal_pa": 100_000.0, "max_step_pa": 20_000.0, "source_pa": 205_000.0}, "150 kPa"),
        ({"nominal_pa": 100_000.0, "max_step_pa": 25_000.0, "source_pa": 150_000.0}, "20 kPa"),
    ],
)
def test_limits_beyond_the_ceilings_are_refused_in_kpa(error_of, module_server, limits, words):
    api = module_server.client()
    before = len(api.list_experiments())
    err = error_of(api.create_experiment, **HW, limits=limits)
    assert err.status == 422 and err.code == "invalid_input", err.detail
    assert words in err.detail and "ceiling" in err.detail, err.detail
    assert len(api.list_experiments()) == before  # nothing stored


def test_limits_within_the_ceilings_are_kept(module_server):
    api = module_server.client()
    limits = {"nominal_pa": 100_000.0, "max_step_pa": 20_000.0, "source_pa": 140_000.0}
    exp = api.create_experiment(**HW, limits=limits)
    assert exp["limits"]["source_pa"] == 140_000.0


def test_an_experiment_wider_than_todays_ceilings_gets_no_schedule_through(error_of, module_server):
    """Made under the paper robot's ceilings (205 kPa, 30 kPa), run on a server whose robot
    allows 150 kPa and 20 kPa steps: suggest, attach, confirm and claim all refuse it."""
    db = Database(module_server.db_url)
    try:
        with db.write() as s:
            spec = ExperimentCreate(
                **HW,
                limits={"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0},
            )
            actor = Actor("operator", "operator")
            exp_id = create_experiment(s, spec, actor=actor, ceilings=HardwareCeilings()).id
        with db.write() as s:  # a trial of it, proposed before the robot changed
            old = attach(s, exp_id, [0.99] * 10, note="", actor=actor, ceilings=HardwareCeilings())
    finally:
        db.dispose()
    api = module_server.client()
    for call, args in ((api.suggest, (exp_id,)), (api.attach_trial, (exp_id, [0.5] * 10))):
        err = error_of(call, *args)
        assert err.status == 422 and err.code == "safety_violation", err.detail
        assert "ceiling" in err.detail and "150 kPa" in err.detail, err.detail
    for call, args in (
        (api.preview, (old.id,)),
        (api.confirm_trial, (old.id, old.schedule_hash)),
    ):
        err = error_of(call, *args)
        assert err.status == 422 and err.code == "safety_violation", err.detail
        assert "ceiling" in err.detail, err.detail
    assert [t["id"] for t in api.list_trials(exp_id)] == [old.id]
    assert api.get_trial(old.id)["status"] == "awaiting_confirmation"
