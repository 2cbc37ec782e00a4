"""The sim prior and sim twins over HTTP: linking (at creation, later, refused in words, by
role), starting one, the prior in the suggestion basis, the sim trials outside the hardware
budget, the twin made in the server's compute processes and handed to the hardware worker."""

from __future__ import annotations

import pytest

from app.client import HandfulAPIError

SERVER_ENV = {"HANDFUL_TWIN_INTERVAL_S": "0.2"}
HARDWARE_LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0}
NEW_EXP = {"sim_preset": "fast"}


@pytest.fixture(autouse=True)
def _nothing_left_queued(module_server):
    """Each test ends with no claimable trial (claims take the oldest first)."""
    yield
    op = module_server.client("operator")
    for exp in op.list_experiments():
        if exp["status"] == "active":
            op.patch_experiment(exp["id"], status="archived")


def test_linking_over_http(op, module_server, new_exp):
    sim = new_exp(op, name="sim", limits=HARDWARE_LIMITS)
    hw = new_exp(op, name="hw", target="hardware", sim_prior_experiment_id=sim["id"])
    assert hw["sim_prior_experiment_id"] == sim["id"]
    n = len(op.list_experiments())
    # refused at creation, in words, nothing stored
    other = new_exp(op, name="sim P=5", levels=5, command_hold="linear")
    with pytest.raises(HandfulAPIError) as err:
        new_exp(op, name="bad", target="hardware", sim_prior_experiment_id=other["id"])
    assert err.value.status == 422 and err.value.code == "invalid_input"
    assert "the pressure levels P differ (3 here, 5 there)" in err.value.detail
    assert "the command hold differs" in err.value.detail
    assert len(op.list_experiments()) == n + 1  # only "sim P=5"
    # later: refused, then relinked and unlinked; a viewer may not
    with pytest.raises(HandfulAPIError) as err:
        op.link_sim_prior(hw["id"], other["id"])
    assert err.value.status == 422 and "cannot be the sim prior" in err.value.detail
    viewer = module_server.client("viewer")
    with pytest.raises(HandfulAPIError) as err:
        viewer.link_sim_prior(hw["id"], sim["id"])
    assert err.value.status == 403
    assert op.unlink_sim_prior(hw["id"])["sim_prior_experiment_id"] is None
    assert op.link_sim_prior(hw["id"], sim["id"])["sim_prior_experiment_id"] == sim["id"]
    got = viewer.sim_prior(hw["id"])
    assert (got["sim_experiment_id"], got["twin_preset"], got["n_scored"]) == (sim["id"], "fast", 0)
    actions = [a["action"] for a in op.audit(hw["id"])]
    assert actions.count("experiment.sim_prior") == 3  # linked, unlinked, linked


def test_start_one_and_the_twin_at_the_worker(op, worker, new_exp):
    hw = new_exp(op, name="hw", target="hardware", budget=3)
    started = op.start_sim_prior(hw["id"], n_trials=3)
    sim = started["sim_experiment"]
    assert started["experiment"]["sim_prior_experiment_id"] == sim["id"]
    assert len(started["queued"]) == 3 and sim["target"] == "sim"
    # the sim workers' trials: claimed and scored like any (here: one worker client)
    for claim in worker.claim("sim-w", "sim", max_trials=3):
        worker.report_result(
            claim["trial"]["id"], claim["lease_id"], objective=1.0 + claim["trial"]["index"]
        )
    assert op.sim_prior(hw["id"])["n_scored"] == 3
    # the prior reaches the hardware optimiser (random search: warm-started by the best sim θ)
    [t] = op.suggest(hw["id"])
    assert t["suggestion_basis"]["mode"] == "warmstart" and t["suggestion_basis"]["n_prior"] == 3
    assert t["suggestion_basis"]["step"] == "prior"
    assert op.get_experiment(hw["id"])["n_budget_used"] == 1  # 3 sim trials: not counted
    # the twin of its plan is made by the server, then handed to the hardware worker
    planned = op.wait_twin(t["id"], "planned", timeout_s=60)
    assert planned["status"] == "done" and planned["schedule_hash"] == t["schedule_hash"]
    assert planned["predicted_tip_speed"] > 0
    op.preview_and_confirm(t)
    [claim] = worker.claim("hw-w", "hardware")
    assert claim["twin"]["predicted_objective"] == planned["predicted_objective"]
    worker.report_result(t["id"], claim["lease_id"], objective=1.5)
    executed = op.wait_twin(t["id"], "executed", timeout_s=60)
    assert executed["predicted_objective"] == planned["predicted_objective"]
    [row] = op.experiment_twins(hw["id"])
    assert row["discrepancy"] == pytest.approx(1.5 - planned["predicted_objective"])
    assert [x["kind"] for x in op.get_trial(t["id"])["twins"]] == ["planned", "executed"]
